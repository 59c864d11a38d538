"""tools/play.py: recording, one-line errors for bad arguments, a missing display, an output that
cannot be written or already exists (subprocess runs, plus in-process runs where a failure has
to be simulated)."""

from __future__ import annotations

import errno
import importlib.util
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import REPO_ROOT, load_tool, run_tool, tool_env

PLAY = REPO_ROOT / "tools" / "play.py"
NO_DISPLAY_VARIABLES = ("DISPLAY", "WAYLAND_DISPLAY", "SDL_VIDEODRIVER")

# Runs play.py with every write under the directory given as first argument refused, as on a
# read-only mount: root ignores permission bits, so chmod cannot make such a directory here.
DENY_WRITES = """
import builtins, errno, io, os, runpy, sys

denied, sys.argv = sys.argv[1], sys.argv[2:]
real_open, real_os_open = io.open, os.open


def refuse(file):
    if str(file).startswith(denied):
        raise PermissionError(errno.EACCES, "Permission denied", str(file))


def open_denying_writes(file, mode="r", *args, **kwargs):
    if set(mode) & set("wax+"):
        refuse(file)
    return real_open(file, mode, *args, **kwargs)


def os_open_denying_writes(path, flags, *args, **kwargs):
    if flags & (os.O_WRONLY | os.O_RDWR | os.O_CREAT):
        refuse(path)
    return real_os_open(path, flags, *args, **kwargs)


builtins.open = io.open = open_denying_writes
os.open = os_open_denying_writes
runpy.run_path(sys.argv[0], run_name="__main__")
"""


def run_play(*args: str, env: dict[str, str] | None = None) -> subprocess.CompletedProcess:
    return run_tool("play.py", *args, env=env)


def assert_one_error_line(done: subprocess.CompletedProcess, start: str) -> None:
    assert done.returncode == 2, done.stderr
    assert len(done.stderr.strip().splitlines()) == 1, done.stderr
    assert done.stderr.startswith(f"error: {start}"), done.stderr


@pytest.fixture(scope="module")
def play():
    """tools/play.py imported as a module, for runs where a failure must be simulated."""
    return load_tool("play.py")


def test_play_records_a_gif_and_refuses_to_overwrite_it(tmp_path: Path) -> None:
    import imageio.v3 as iio

    video = tmp_path / "stop.gif"
    done = run_play("--scenario", "halting_car_v0", "--case", "stop", "--record", str(video))
    assert done.returncode == 0, done.stderr
    assert f"wrote {video} (61 frames)" in done.stdout
    frames = iio.imread(video)
    assert frames.shape == (61, 244, 800, 3)  # the road (200 px), a title and a legend strip
    recorded = video.read_bytes()
    again = run_play("--scenario", "halting_car_v0", "--case", "go", "--record", str(video))
    assert_one_error_line(again, f"output {video} already exists; pass --overwrite")
    assert video.read_bytes() == recorded
    assert sorted(path.name for path in tmp_path.iterdir()) == ["stop.gif"]  # no temp files
    replaced = run_play(
        "--scenario", "halting_car_v0", "--case", "go", "--record", str(video), "--overwrite"
    )
    assert replaced.returncode == 0, replaced.stderr
    assert video.read_bytes() != recorded and iio.imread(video).shape == (61, 244, 800, 3)
    assert sorted(path.name for path in tmp_path.iterdir()) == ["stop.gif"]


@pytest.mark.parametrize(
    "args",
    [
        ["--scenario", "double_merge_v0", "--case", "stop"],
        ["--scenario", "nowhere"],
        ["--scenario", "double_merge_v0", "--control", "car_0"],
        ["--scenario", "double_merge_v0", "--render", "human", "--control", "car_99"],
        ["--scenario", "double_merge_v0", "--record", "movie.avi"],
        ["--scenario", "double_merge_v0", "--seed", "-1"],
        ["--scenario", "double_merge_v0", "--fps", "inf"],
        ["--scenario", "double_merge_v0", "--fps", "1e-300"],
        ["--scenario", "double_merge_v0", "--record", "x.gif", "--fps", "1000"],
    ],
)
def test_play_bad_arguments_give_one_line_and_exit_2(args: list[str]) -> None:
    assert_one_error_line(run_play(*args), "")


HEADLESS = {
    "no display": {},
    "SDL dummy": {"DISPLAY": ":0", "SDL_VIDEODRIVER": "dummy"},
    "SDL offscreen": {"WAYLAND_DISPLAY": "wayland-0", "SDL_VIDEODRIVER": "offscreen"},
}


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="X11/Wayland variables")
@pytest.mark.parametrize("variables", HEADLESS.values(), ids=HEADLESS.keys())
def test_render_human_without_a_display_stops_at_once(variables: dict[str, str]) -> None:
    pytest.importorskip("pygame")
    env = {k: v for k, v in tool_env().items() if k not in NO_DISPLAY_VARIABLES}
    done = run_play("--scenario", "double_merge_v0", "--render", "human", env={**env, **variables})
    assert_one_error_line(done, "--render human needs a display: ")
    assert "--record FILE.gif" in done.stderr and done.stdout == ""  # no episode was played


@pytest.mark.parametrize(
    ("environ", "platform", "seen"),
    [
        ({}, "linux", False),
        ({"DISPLAY": ""}, "linux", False),
        ({"DISPLAY": ":0"}, "linux", True),
        ({"WAYLAND_DISPLAY": "wayland-0"}, "linux", True),
        ({"DISPLAY": ":0", "SDL_VIDEODRIVER": "x11"}, "linux", True),
        ({"DISPLAY": ":0", "SDL_VIDEODRIVER": "Dummy"}, "linux", False),
        ({}, "freebsd14", False),
        ({}, "darwin", True),
        ({}, "win32", True),
        ({"SDL_VIDEODRIVER": "offscreen"}, "win32", False),
    ],
)
def test_display_problem(play, environ: dict[str, str], platform: str, seen: bool) -> None:
    assert (play.display_problem(environ, platform) is None) == seen


def test_render_human_without_pygame_says_how_to_install_it(play, monkeypatch, capsys) -> None:
    find_spec = importlib.util.find_spec
    monkeypatch.setattr(
        importlib.util, "find_spec", lambda name, *a: None if name == "pygame" else find_spec(name)
    )
    with pytest.raises(SystemExit) as done:
        play.main(["--scenario", "double_merge_v0", "--render", "human"])
    assert done.value.code == 2
    assert capsys.readouterr().err == (
        "error: --render human needs pygame: pip install 'smooth-attention[render]'\n"
    )


def test_play_human_window_with_keyboard_control_runs(play, monkeypatch, capsys) -> None:
    """The window and keyboard path, on SDL's dummy driver (play itself refuses it: no window
    would be seen, so its display check is switched off here)."""
    pytest.importorskip("pygame")
    monkeypatch.setenv("SDL_VIDEODRIVER", "dummy")
    monkeypatch.setenv("SDL_AUDIODRIVER", "dummy")
    monkeypatch.setattr(play, "display_problem", lambda environ, platform: None)
    play.main(
        ["--scenario", "double_merge_v0", "--case", "minor", "--render", "human",
         "--control", "car_1", "--fps", "1000"]
    )  # fmt: skip
    assert capsys.readouterr().out.startswith("double_merge_v0 minor seed 0: 60 steps")


@pytest.mark.parametrize("name", ["x.gif", "x.mp4"])
def test_record_into_a_directory_that_refuses_writes_stops_at_once(tmp_path, name) -> None:
    if name.endswith(".mp4"):
        pytest.importorskip("imageio_ffmpeg")
    denied = tmp_path / "read-only"
    denied.mkdir()
    video = denied / name
    done = subprocess.run(
        [sys.executable, "-c", DENY_WRITES, str(denied), str(PLAY), "--scenario", "halting_car_v0",
         "--record", str(video)],
        capture_output=True, text=True, timeout=120, env=tool_env(),
    )  # fmt: skip
    assert_one_error_line(done, f"cannot write {video}: Permission denied")
    assert done.stdout == "" and list(denied.iterdir()) == []


def test_a_write_failing_after_the_episode_leaves_no_file(play, tmp_path, monkeypatch, capsys):
    video = tmp_path / "x.gif"

    def refuse(self, data):
        raise PermissionError(errno.EACCES, "Permission denied", str(self))

    monkeypatch.setattr(Path, "write_bytes", refuse)
    with pytest.raises(SystemExit) as done:
        play.main(["--scenario", "halting_car_v0", "--record", str(video)])
    assert done.value.code == 2
    err = capsys.readouterr().err
    assert err.splitlines()[-1] == f"error: cannot write {video}: Permission denied"
    assert "Traceback" not in err and list(tmp_path.iterdir()) == []


def test_a_file_that_appears_during_the_episode_is_not_overwritten(play, tmp_path, monkeypatch):
    video = tmp_path / "x.gif"
    real_play = play.play

    def play_while_someone_writes_the_output(args, case):
        video.write_text("someone else's")
        return real_play(args, case)

    monkeypatch.setattr(play, "play", play_while_someone_writes_the_output)
    with pytest.raises(SystemExit) as done:
        play.main(["--scenario", "halting_car_v0", "--record", str(video)])
    assert done.value.code == 2
    assert video.read_text() == "someone else's" and os.listdir(tmp_path) == ["x.gif"]


def test_play_records_an_mp4(tmp_path: Path) -> None:
    pytest.importorskip("imageio_ffmpeg")
    import imageio.v3 as iio

    video = tmp_path / "minor.mp4"
    done = run_play("--scenario", "double_merge_v0", "--case", "minor", "--record", str(video))
    assert done.returncode == 0, done.stderr
    assert "WARNING" not in done.stderr  # frames padded to H.264 macro blocks, not resized
    frames = iio.imread(video)
    assert frames.shape == (61, 256, 800, 3)  # 244 px of road, title and legend, padded to 16


# ---- what the frames say -----------------------------------------------------------------------
def _steered_env_module(real, removed: dict):
    """`scenarios.env_module` whose environments steer car_0 hard left at full throttle (so it
    leaves the episode within seconds) and note in `removed` each agent's removal step and
    step info, as the environment reports them."""

    def env_module(name):
        module = real(name)

        class Steered:
            @staticmethod
            def parallel_env(**kwargs):
                env = module.parallel_env(**kwargs)
                expert, step, count = env.unwrapped.expert_actions, env.step, [0]

                def actions():
                    chosen = expert()
                    if "car_0" in chosen:
                        chosen["car_0"] = np.array([0.3, 2.0], dtype=np.float32)
                    return chosen

                def stepping(chosen):
                    result = step(chosen)
                    count[0] += 1
                    for agent, done in result[2].items():
                        if done:
                            removed.setdefault(agent, (count[0], result[4][agent]))
                    return result

                env.unwrapped.expert_actions, env.step = actions, stepping
                return env

        return Steered

    return env_module


def test_a_car_that_leaves_is_named_on_screen_with_the_reason(play, tmp_path, capsys, monkeypatch):
    from pipeline.frames import NOTICE_COLOR, NOTICE_SECONDS

    removed: dict = {}
    monkeypatch.setattr(play, "env_module", _steered_env_module(play.env_module, removed))
    shown, real_annotate = [], play.annotate

    def annotate(frame, title, legend, notices=()):
        shown.append((list(notices), real_annotate(frame, title, legend, notices)))
        return shown[-1][1]

    monkeypatch.setattr(play, "annotate", annotate)
    video = tmp_path / "crash.gif"
    play.main(["--scenario", "halting_car_v3", "--case", "stop", "--record", str(video)])
    assert "car_0" in removed
    reasons = {
        agent: " and ".join(
            text
            for key, text in (("collided", "collided"), ("off_road", "left the road"))
            if info[key]
        )
        for agent, (_, info) in removed.items()
    }
    out = capsys.readouterr().out
    assert f"car_0: {reasons['car_0']}" in out
    what = {"main_green": "follower (green)", "main_brown": "leader, may stop (brown)"}
    duration = math.ceil(NOTICE_SECONDS / 0.3)  # Halting Car records every 0.3 s
    assert len(shown) == 61  # the frame before the first step, then one a step
    for step, (notices, frame) in enumerate(shown):
        expected = [
            f"{agent}, {what.get(info['role'], 'another car')}, left the episode: {reasons[agent]}"
            for agent, (at, info) in sorted(removed.items())
            if at <= step < at + duration
        ]
        assert notices == expected, step
        red = (frame[22:122, :] == NOTICE_COLOR).all(axis=-1).sum()  # the road's top
        assert (red > 0) == bool(expected), step
    assert any(notices for notices, _ in shown) and not shown[0][0]
    assert iio_frames(video) == len(shown)


def iio_frames(path: Path) -> int:
    import imageio.v3 as iio

    return len(iio.imread(path))


def test_every_frame_has_a_title_and_a_legend_of_the_car_colours(play, tmp_path, capsys):
    from carlo_lite.render import ROLE_COLORS
    from pipeline.frames import STRIP_COLOR, STRIP_PX

    args = play.parse_args(["--scenario", "double_merge_v1", "--record", str(tmp_path / "a.gif")])
    _, frames = play.play(args, "major")
    assert len(frames) == 61
    for frame in (frames[0], frames[-1]):
        assert frame.shape == (200 + 2 * STRIP_PX, 800, 3)
        title, legend = frame[:STRIP_PX], frame[-STRIP_PX:]
        assert (title != STRIP_COLOR).any(axis=-1).sum() > 100  # the title's text
        for color in ROLE_COLORS.values():  # a swatch of every car colour
            assert (legend == color).all(axis=-1).sum() >= 50, color
    assert not np.array_equal(frames[0][:STRIP_PX], frames[-1][:STRIP_PX])  # the time moved


def test_the_removal_reason_comes_from_the_step_info():
    from pipeline.frames import removal_notice, removal_reason

    assert removal_reason({"collided": True, "off_road": False}) == "collided"
    assert removal_reason({"collided": False, "off_road": True}) == "left the road"
    assert removal_reason({"collided": True, "off_road": True}) == "collided and left the road"
    info = {"role": "main_brown", "collided": False, "off_road": True}
    assert removal_notice("halting_car_v2", "car_1", info) == (
        "car_1, leader, may stop (brown), left the episode: left the road"
    )
    info = {"role": "distractor", "collided": True, "off_road": False}
    assert removal_notice("double_merge", "car_9", info) == (
        "car_9, another car, left the episode: collided"
    )
