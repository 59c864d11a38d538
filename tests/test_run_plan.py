"""The reproduction's plan (pipeline.protocol, pipeline.run_plan): settings and groups, the
quick protocol's sizes, the jobs of a setting, their cache keys and paths, the figure scenes,
and the pool's deadline. The runner itself is tested end to end in test_reproduce.py."""

from __future__ import annotations

import dataclasses
import json
import re
import time
from pathlib import Path

import numpy as np

from pipeline import reproduction, result_store, run_plan
from pipeline.protocol import ALL_VARIANTS, GROUPS, SETTING_BY_NAME, Protocol, pick


def test_settings_and_groups_expand_in_canonical_order():
    names = pick("hc_go,main,dm_r0.3", tuple(SETTING_BY_NAME), GROUPS, "setting")
    assert names == ("dm_r0.3", "hc_stop", "hc_go")
    assert GROUPS["size"] == ("dm_3+10", "dm_15+30", "dm_30+100")


def test_quick_caps_the_major_count_and_keeps_small_settings():
    by_name = SETTING_BY_NAME
    quick = Protocol(tuple(by_name.values()), ALL_VARIANTS, 2, 1, quick=True)
    full = Protocol(tuple(by_name.values()), ALL_VARIANTS, 10, 200)
    assert quick.counts(by_name["dm_3+10"]) == (10, 3)
    assert quick.counts(by_name["dm_r0.8"]) == (10, 8)  # 40 * 10/50
    assert quick.counts(by_name["dm_30+100"]) == (10, 3)
    assert full.counts(by_name["dm_15+30"]) == (30, 15)
    assert full.counts(by_name["hc_go"]) == (50, 15)


def test_jobs_cover_every_variant_and_seed(tmp_path):
    setting = SETTING_BY_NAME["hc_go"]
    protocol = Protocol((setting,), ALL_VARIANTS, 3, 7)
    jobs = run_plan.setting_jobs(protocol, setting, tmp_path)
    assert len(jobs) == 5 * 3 + 4  # five trained variants x 3 seeds, four baselines once
    assert {(j.variant, j.seed) for j in jobs if j.save_scenes} == {("ours", 0), ("s_attn", 0)}
    data = Path(jobs[0].data_path)
    assert data.parent == tmp_path / "data"
    assert re.fullmatch(r"halting_car_v1_go-major_15\+50_test50_seed0_[0-9a-f]{8}\.h5", data.name)
    assert all(j.data_path == jobs[0].data_path for j in jobs)
    assert re.fullmatch(r"seed0_ep7_[0-9a-f]{8}", Path(jobs[0].run_dir).name)
    assert Path(jobs[0].run_dir).parent.name == "ours" and jobs[-1].run_dir.endswith(
        "ridge_labelled_relation"
    )
    names = {Path(j.run_dir).name for j in jobs if j.variant == "s_attn"}
    assert len(names) == 3


def test_cache_keys_change_with_the_configs(tmp_path):
    setting = SETTING_BY_NAME["dm_r0.3"]
    protocol = Protocol((setting,), ("ours",), 1, 5)
    spec = run_plan.data_spec(protocol, setting)
    other = dataclasses.replace(spec, scenario_digest=run_plan.digest({"changed": 1}))
    assert spec.stem != other.stem

    def key(variant: str, seed: int, epochs: int) -> str:
        return run_plan.run_dir(tmp_path, spec, variant, seed, epochs).name.split("_")[-1]

    keys = {key("ours", 0, 5), key("nonsmooth", 0, 5), key("ours", 1, 5), key("ours", 0, 6)}
    assert len(keys) == 4 and key("ours", 0, 5) == key("ours", 0, 5)
    agent = run_plan.run_dir(tmp_path, spec, "ours", 0, 5, "agent").name.split("_")[-1]
    assert agent not in keys  # another preset is another run
    job = run_plan.setting_jobs(dataclasses.replace(protocol, preset="agent"), setting, tmp_path)
    assert job[0].preset == "agent" and job[0].run_dir.endswith(agent)
    model_cfg, train_cfg = run_plan.run_configs("ours", 0, 5, "agent")
    assert model_cfg.frame == "agent" and train_cfg.epochs == 5 and train_cfg.threads == 1
    assert run_plan.digest({"a": 1, "b": 2}) == run_plan.digest({"b": 2, "a": 1})


def test_compared_presets_add_their_variants_jobs_named_apart(tmp_path):
    """--compare-presets: each compared preset's runs of the compared variants are planned
    after the protocol's own, under their own cache keys, with no figure scenes, and named
    "<variant>@<preset>" in the records; a variant the compared preset leaves unchanged
    (S-Attn has no highway under either agent preset) shares the run and is run once."""
    setting = SETTING_BY_NAME["hc_go"]
    protocol = Protocol(
        (setting,),
        ("ours", "s_attn", "const_vel"),
        2,
        5,
        preset="agent",
        compare_presets=("agent_zero_cv",),
        compare_variants=("ours", "s_attn"),
    )
    jobs = run_plan.setting_jobs(protocol, setting, tmp_path)
    main, compared = jobs[:5], jobs[5:]
    assert [(j.variant, j.seed, j.compared) for j in main] == [
        ("ours", 0, False),
        ("ours", 1, False),
        ("s_attn", 0, False),
        ("s_attn", 1, False),
        ("const_vel", 0, False),
    ]
    assert [(j.record_variant, j.seed, j.preset) for j in compared] == [
        ("ours@agent_zero_cv", 0, "agent_zero_cv"),
        ("ours@agent_zero_cv", 1, "agent_zero_cv"),
        ("s_attn@agent_zero_cv", 0, "agent_zero_cv"),
        ("s_attn@agent_zero_cv", 1, "agent_zero_cv"),
    ]
    assert main[0].record_variant == "ours" and not any(j.save_scenes for j in compared)
    assert compared[0].run_dir != main[0].run_dir  # the highway's refit differs: another key
    assert compared[2].run_dir == main[2].run_dir  # S-Attn's configuration is the same
    once = run_plan.unique_runs(jobs)
    assert len(once) == 7 and compared[2] not in once and main[2] in once
    assert [j.compared for j in run_plan.unique_runs(list(reversed(jobs)))].count(True) == 2


def test_a_compared_preset_limited_to_some_settings_is_planned_only_there(tmp_path):
    """compare_only ("paper@main"): the paper preset's runs on the main settings, none elsewhere."""
    protocol = Protocol(
        (SETTING_BY_NAME["dm_r0.3"], SETTING_BY_NAME["dm_r0.8"]),
        ("ours",),
        1,
        5,
        preset="agent",
        compare_presets=("agent_zero_cv", "paper"),
        compare_only=(("paper", ("dm_r0.3", "hc_stop")),),
    )
    planned = {
        setting.name: [j.record_variant for j in run_plan.setting_jobs(protocol, setting, tmp_path)]
        for setting in protocol.settings
    }
    assert planned == {
        "dm_r0.3": ["ours", "ours@agent_zero_cv", "ours@paper"],
        "dm_r0.8": ["ours", "ours@agent_zero_cv"],
    }


def test_collect_names_the_compared_presets_runs_apart(tmp_path):
    """Runs found in the results store are read into records named by Job.record_variant."""
    setting = SETTING_BY_NAME["hc_go"]
    protocol = Protocol(
        (setting,), ("ours",), 1, 5, preset="agent", compare_presets=("agent_zero_cv",)
    )
    scores = {"cases": {"go": {"ade": 1.0}, "stop": {"ade": 2.0}}, "overall": {"ade": 1.5}}
    for k, job in enumerate(run_plan.setting_jobs(protocol, setting, tmp_path, tmp_path / "s")):
        result = {
            "variant": job.variant,
            "seed": job.seed,
            "major_case": "go",
            "case_names": ["stop", "go"],
            "main_agents": scores,
            "all_agents": scores,
            "attention_accuracy": {"cases": {"go": {}, "stop": {}}, "overall": {}},
            "train_seconds": float(k),
        }
        Path(job.store_dir).mkdir(parents=True)
        (Path(job.store_dir) / "eval.json").write_text(json.dumps(result))
        if job.save_scenes:
            (Path(job.store_dir) / "scenes.npz").write_bytes(b"")
    found = result_store.collect(protocol, tmp_path, tmp_path / "s")
    assert [(r.variant, r.train_seconds) for r in found] == [
        ("ours", 0.0),
        ("ours@agent_zero_cv", 1.0),
    ]


def test_figure_scenes_pick_the_first_interacting_scene_per_case():
    case = np.array([1, 0, 0, 1, 0])
    interaction = np.zeros((5, 4), dtype=bool)
    interaction[2, 1] = interaction[4, 3] = True
    assert reproduction.figure_scenes(case, interaction, 2) == [2, 0]  # case 1: none -> first


def test_run_parallel_starts_nothing_after_its_deadline():
    from pipeline.pool import run_parallel

    assert run_parallel(abs, [-1, -2, 3], 2, "t", deadline=time.monotonic() - 1.0) == [None] * 3
    assert run_parallel(abs, [-1, -2, 3], 2, "t", deadline=time.monotonic() + 600.0) == [1, 2, 3]


def test_settings_use_the_v1_scenarios():
    scenarios = {name: setting.scenario for name, setting in SETTING_BY_NAME.items()}
    assert len(scenarios) == 7
    assert {s for n, s in scenarios.items() if n.startswith("dm_")} == {"double_merge_v1"}
    assert {s for n, s in scenarios.items() if n.startswith("hc_")} == {"halting_car_v1"}


def test_cache_keys_leave_out_added_switches_at_their_former_values():
    from predictor.presets import make_configs
    from predictor.stored_config import ADDED_MODEL_FIELDS, config_key, config_to_dict

    model, train = make_configs("ours", preset="paper", seed=0, epochs=5)
    key = config_key(model)
    # the paper's model: every added switch holds its former value, so none is in the key, and
    # the key is what a version before those switches would have written
    assert not set(ADDED_MODEL_FIELDS) & set(key)
    assert key == {k: v for k, v in config_to_dict(model).items() if k not in ADDED_MODEL_FIELDS}
    assert "bucket_batches" in config_key(train)  # on here: not its former value (off)
    radius, _ = make_configs("ours", {"neighbours": "radius"}, preset="paper")
    assert config_key(radius)["neighbours"] == "radius"  # a switch in use stays in the key


def test_a_compiled_protocol_plans_the_eager_runs_and_a_resumed_run_keeps_its_mode(
    tmp_path, monkeypatch
):
    """`Protocol.compile_graph_step` changes how new runs train, not their keys; a run resumed
    from its last.pt trains on in that checkpoint's mode (training is stubbed here:
    test_compiled_step.py trains compiled for real)."""
    import torch

    import predictor.training
    from predictor.checkpoints import CHECKPOINT_FORMAT, CHECKPOINT_VERSION

    setting = SETTING_BY_NAME["hc_go"]
    eager = Protocol((setting,), ("ours",), 2, 3)
    compiled = dataclasses.replace(eager, compile_graph_step=True)
    jobs = run_plan.setting_jobs(compiled, setting, tmp_path)
    assert [j.run_dir for j in jobs] == [
        j.run_dir for j in run_plan.setting_jobs(eager, setting, tmp_path)
    ]
    assert all(j.compile_graph_step for j in jobs)
    asked = []
    monkeypatch.setattr(
        predictor.training, "train", lambda data, model, train, out, **kw: asked.append(train)
    )
    new, begun_eager = jobs
    Path(begun_eager.run_dir).mkdir(parents=True)
    begun = {"format": CHECKPOINT_FORMAT, "version": CHECKPOINT_VERSION, "train_config": {}}
    torch.save(begun, Path(begun_eager.run_dir) / "last.pt")  # an eager run's, before the switch
    (Path(begun_eager.run_dir) / "config.json").write_text(json.dumps({"train": {}}))
    assert reproduction.train_job(new) == "trained"
    assert reproduction.train_job(begun_eager) == "resumed"
    assert [cfg.compile_graph_step for cfg in asked] == [True, False]
    assert reproduction.stored_graph_step(Path(begun_eager.run_dir)) == "eager"
    (Path(begun_eager.run_dir) / "config.json").write_text(
        json.dumps({"train": {"compile_graph_step": True}})
    )
    assert reproduction.stored_graph_step(Path(begun_eager.run_dir)) == "compiled"
