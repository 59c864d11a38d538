"""The registry of scenario versions: names Gymnasium's way (exact, bare family = latest with a
notice, bad names listing the valid ones), settings that accumulate from one entry per
version, the environment modules made from it (import, pickle, pydoc), the docs table kept in
sync, and the published results' dataset keys unchanged."""

from __future__ import annotations

import dataclasses
import pickle
import re
import subprocess
import sys
import warnings
from pathlib import Path

import pytest
from conftest import REPO_ROOT, run_tool

import scenarios
from pipeline.generation import GenerateConfig
from pipeline.run_plan import digest
from scenarios import (
    FAMILIES,
    VERSIONS,
    LatestVersionNotice,
    ReactiveHaltingCar,
    env_module,
    lookup,
    resolve,
    stored_version,
)
from scenarios.env_modules import EnvironmentModule
from scenarios.registry import versions_markdown
from scenarios.versioning import Version, family_versions


def test_every_family_numbers_its_versions_from_zero():
    assert list(FAMILIES) == ["double_merge", "halting_car", "left_turn", "roundabout_entry"]
    for family, versions in FAMILIES.items():
        assert [v.number for v in versions] == list(range(len(versions)))
        assert all(v.name == f"{family}_v{v.number}" for v in versions)
    assert list(VERSIONS) == [v.name for versions in FAMILIES.values() for v in versions]


def test_settings_accumulate_and_each_entry_changes_exactly_its_fields():
    """A version with the previous version's code differs from it in exactly the fields its
    entry names; one with new code starts from that code's defaults."""
    for versions in FAMILIES.values():
        for previous, version in zip(versions, versions[1:]):
            now = dataclasses.asdict(version.config())
            if version.scenario_class is not previous.scenario_class:
                assert version.config() == version.scenario_class.config_class(
                    **version.own_settings
                )
                continue
            before = dataclasses.asdict(previous.config())
            changed = {key for key in now if now[key] != before[key]}
            assert changed == set(version.own_settings) != set(), version.name
    assert VERSIONS["halting_car_v3"].config().brake_start_s == (2.4, 3.0)  # v2's, kept


def test_a_family_from_entries_builds_versions_and_refuses_bad_ones():
    versions = family_versions(
        "toy",
        "Toy",
        Version("first", "why", code=ReactiveHaltingCar),
        Version("slower", "why", settings={"cruise_speed_mps": (5.0, 6.0)}),
        Version("later", "why", settings={"brake_start_s": (2.0, 2.5)}),
    )
    assert [v.name for v in versions] == ["toy_v0", "toy_v1", "toy_v2"]
    assert versions[2].config().cruise_speed_mps == (5.0, 6.0)
    assert versions[2].make().name == "toy_v2"
    module = EnvironmentModule(versions[2], versions)  # what scenarios makes for a registered one
    env = module.parallel_env()
    env.reset(seed=0)
    assert env.metadata["name"] == "toy_v2" and "toy_v2" in type(env).__doc__
    with pytest.raises(ValueError, match="toy_v0 must name its code"):
        family_versions("toy", "Toy", Version("x", "y", settings={}))
    with pytest.raises(TypeError, match="no_such_field"):
        family_versions(
            "toy", "Toy", Version("x", "y", code=ReactiveHaltingCar, settings={"no_such_field": 1})
        )


LATEST_HALTING_CAR = FAMILIES["halting_car"][-1].name  # so a new version needs no test edits
LATEST_DOUBLE_MERGE = FAMILIES["double_merge"][-1].name


def test_names_resolve_as_gymnasium_does():
    assert lookup("halting_car_v0") == (VERSIONS["halting_car_v0"], None)
    version, notice = lookup("halting_car")
    assert version.name == LATEST_HALTING_CAR and version.number == len(FAMILIES["halting_car"]) - 1
    assert f"latest version {LATEST_HALTING_CAR}" in notice and "'halting_car'" in notice
    with pytest.warns(LatestVersionNotice, match=LATEST_HALTING_CAR):
        assert resolve("halting_car") is version
    with pytest.warns(LatestVersionNotice, match=LATEST_DOUBLE_MERGE):
        assert env_module("double_merge") is getattr(scenarios, LATEST_DOUBLE_MERGE)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert scenarios.make("halting_car_v2").name == "halting_car_v2"
    with pytest.raises(ValueError) as error:
        lookup("haltingcar_v3")
    message = str(error.value)
    assert message.startswith("unknown scenario 'haltingcar_v3' (did you mean halting_car_v3?)")
    assert all(name in message for name in VERSIONS) and "\n" not in message


def test_files_from_before_versioned_names_map_to_v0():
    assert stored_version("halting_car") is VERSIONS["halting_car_v0"]
    assert stored_version("double_merge") is VERSIONS["double_merge_v0"]
    assert stored_version("halting_car_v2") is VERSIONS["halting_car_v2"]


def test_the_generator_records_the_exact_version():
    with pytest.warns(LatestVersionNotice):
        config = GenerateConfig.for_scenario("halting_car", minor_ratio=0.3)
    assert config.scenario == LATEST_HALTING_CAR
    with pytest.raises(ValueError, match=f"must name a version, e.g. {LATEST_HALTING_CAR}"):
        GenerateConfig("halting_car", "stop", "go")


def test_environment_modules_import_pickle_and_document_like_files(tmp_path):
    env = scenarios.halting_car_v2.parallel_env()
    env.reset(seed=1)
    clone = pickle.loads(pickle.dumps(env))
    assert type(clone) is type(env) and type(env).__name__ == "HaltingCarV2Env"
    assert scenarios.halting_car_v2.raw_env is scenarios.halting_car_v2.HaltingCarV2Env
    assert "raw_env" in dir(scenarios.halting_car_v2)
    code = (
        "import pickle, sys, scenarios.halting_car_v2 as m;"
        "sys.stdout.buffer.write(pickle.dumps(m.parallel_env()))"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, cwd=REPO_ROOT)
    assert done.returncode == 0, done.stderr.decode()
    assert pickle.loads(done.stdout).metadata["name"] == "halting_car_v2"
    shown = subprocess.run(
        [sys.executable, "-m", "pydoc", "scenarios.halting_car_v3.raw_env"],
        capture_output=True,
        text=True,
        cwd=REPO_ROOT,
    )
    assert shown.returncode == 0 and "## Version History" in shown.stdout
    with pytest.raises(AttributeError, match="has no attribute 'nothing'"):
        scenarios.halting_car_v3.nothing  # noqa: B018


def test_the_docs_table_is_the_registrys():
    text = (REPO_ROOT / "docs" / "scenarios.md").read_text()
    marked = r"<!-- versions table:.*?-->\n(.*?)<!-- end of versions table -->"
    table = re.search(marked, text, re.S)
    assert table is not None and table[1] == versions_markdown(), (
        "docs/scenarios.md's versions table is out of date: replace it with the output of "
        "`python tools/list_scenarios.py --markdown`"
    )
    listed = run_tool("list_scenarios.py")
    assert listed.returncode == 0
    for latest in (LATEST_HALTING_CAR, LATEST_DOUBLE_MERGE):
        assert f"{latest} (latest)" in listed.stdout


def test_the_published_results_keep_their_dataset_keys():
    """results/ keys each dataset by a digest of its scenario's configuration: the versions the
    protocol uses must give the digests its folders carry, or the cache would miss."""
    folders = [path.name for path in (REPO_ROOT / "results").iterdir() if path.is_dir()]
    keys = {re.match(r"(.+_v\d)_.*_([0-9a-f]{8})$", name).groups() for name in folders}
    assert {name for name, _ in keys} == {"double_merge_v1", "halting_car_v1"}
    for name, key in keys:
        assert digest(dataclasses.asdict(VERSIONS[name].config())) == key, name


def test_no_stray_environment_files():
    """The environment modules come from the registry: none is a file in scenarios/."""
    files = {path.stem for path in Path(scenarios.__file__).parent.glob("*_v[0-9]*.py")}
    assert files == set()
