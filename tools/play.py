"""Play one episode of a scenario: watch it, record it, or drive one car yourself.

    python tools/play.py --scenario double_merge_v1 --case minor --render human
    python tools/play.py --scenario halting_car_v3 --case stop --record stop.gif
    python tools/play.py --scenario double_merge_v1 --render human --control car_0

Every frame, in the window and in a recording, has a title (scenario, case, time), a legend of the
car colours and, for a few seconds after a car leaves the episode, a red notice saying which car
and why (collided, left the road).

The expert drives every car except the one given to --control, which you steer with the arrow
keys (left/right: steer, up: accelerate, down: brake; Esc or closing the window ends the
episode). --render human needs pygame and a display: without one (no DISPLAY or WAYLAND_DISPLAY
on Linux, or SDL_VIDEODRIVER=dummy/offscreen) it stops at once with one line instead of playing
to an invisible window. --record writes the frames as a .gif (or .mp4 when imageio-ffmpeg is
installed), headless, atomically, refusing to replace an existing file without --overwrite. The
same arguments give the same episode.
"""

from __future__ import annotations

import argparse
import importlib
import importlib.util
import math
import os
import sys
import tempfile
from collections.abc import Mapping
from pathlib import Path

import numpy as np
from tqdm import tqdm

from pipeline.cli import (
    INTERRUPTED,
    ArgumentParser,
    check_output,
    fail,
    run_main,
    write_failure_code,
    writing,
)
from pipeline.frames import (
    NOTICE_SECONDS,
    Notice,
    active_notices,
    annotate,
    legend_entries,
    removal_notice,
    removal_reason,
)
from scenarios import VERSIONS, choices_text, env_module, lookup

STEER_RAD = 0.12  # steering while an arrow key is held
ACCEL_MPS2, BRAKE_MPS2 = 2.0, -5.0
VIDEO_SUFFIXES = (".gif", ".mp4")
HEADLESS_SDL_DRIVERS = ("dummy", "offscreen")  # SDL video drivers that never show a window
MIN_FPS = 0.1  # slowest frame rate: a frame stays 10 s
MAX_VIDEO_FPS = 100.0  # a GIF stores each frame's delay in hundredths of a second


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--scenario",
        required=True,
        help=f"scenario version, family_vN; a family name means its latest ({choices_text()})",
    )
    parser.add_argument("--case", help="case to play (default: the scenario's major case)")
    parser.add_argument("--seed", type=int, default=0, help="episode seed (default 0)")
    parser.add_argument("--render", choices=("human", "none"), default="none")
    parser.add_argument("--record", metavar="FILE", help="write a video (.gif or .mp4)")
    parser.add_argument("--overwrite", action="store_true", help="replace an existing video")
    parser.add_argument("--control", metavar="AGENT", help="drive this car (e.g. car_0)")
    parser.add_argument(
        "--fps", type=float, help="frame rate of the window and the video (default: real time)"
    )
    return parser.parse_args(argv)


def check_args(args: argparse.Namespace) -> tuple[str, Path | None]:
    """Validate what argparse cannot (one-line error, exit 2); returns (case, video path)."""
    try:
        version, notice = lookup(args.scenario)
    except ValueError as error:
        fail(f"--scenario: {error}")
    if notice is not None:
        print(f"notice: {notice}", file=sys.stderr)
    args.scenario = version.name
    scenario = version.scenario_class
    case = args.case or scenario.default_major_case
    if case not in scenario.case_names:
        fail(f"--case must be one of {', '.join(scenario.case_names)} for {args.scenario}")
    if args.seed < 0:
        fail(f"--seed must be non-negative, got {args.seed}")
    if args.fps is not None and not MIN_FPS <= args.fps < math.inf:
        fail(f"--fps must be a finite number >= {MIN_FPS:g}, got {args.fps}")
    if args.fps is not None and args.record is not None and args.fps > MAX_VIDEO_FPS:
        fail(f"--fps of a recording must be at most {MAX_VIDEO_FPS:g}, got {args.fps}")
    if args.control is not None:
        agents = [f"car_{i}" for i in range(version.config().num_cars)]
        if args.control not in agents:
            fail(f"--control must name an agent car_0 ... {agents[-1]}, got {args.control!r}")
        if args.render != "human":
            fail("--control needs --render human (the keyboard is read from the window)")
    if args.render == "human":
        check_window()
    video = None
    if args.record is not None:
        video = check_output(args.record, args.overwrite)
        if video.suffix.lower() not in VIDEO_SUFFIXES:
            fail(f"--record must end in {' or '.join(VIDEO_SUFFIXES)}, got {video.name}")
        if video.suffix.lower() == ".mp4" and importlib.util.find_spec("imageio_ffmpeg") is None:
            fail("writing .mp4 needs imageio-ffmpeg (pip install imageio-ffmpeg); use .gif")
        check_writable(video)
    return case, video


def check_writable(video: Path) -> None:
    """Exit 2 with one line now, not after the episode, if `video`'s directory refuses a new
    file (a read-only mount refuses even root, which permission bits do not)."""
    try:
        with tempfile.NamedTemporaryFile(dir=video.parent, prefix=f".{video.stem}.probe."):
            pass
    except OSError as error:
        fail(f"cannot write {video}: {error.strerror or error}")


def display_problem(environ: Mapping[str, str], platform: str) -> str | None:
    """Why a window could not be seen (None if it can): SDL set to a headless video driver, or,
    on X11/Wayland systems (not macOS or Windows), neither DISPLAY nor WAYLAND_DISPLAY set."""
    driver = environ.get("SDL_VIDEODRIVER", "").strip().lower()
    if driver in HEADLESS_SDL_DRIVERS:
        return f"SDL_VIDEODRIVER={driver} shows no window"
    if platform not in ("darwin", "win32", "cygwin") and not (
        environ.get("DISPLAY") or environ.get("WAYLAND_DISPLAY")
    ):
        return "no display is available (neither DISPLAY nor WAYLAND_DISPLAY is set)"
    return None


def check_window() -> None:
    """Exit 2 with one line unless --render human can open a visible window."""
    if importlib.util.find_spec("pygame") is None:
        fail("--render human needs pygame: pip install 'smooth-attention[render]'")
    problem = display_problem(os.environ, sys.platform)
    if problem is not None:
        fail(f"--render human needs a display: {problem}; record a video with --record FILE.gif")


class Keyboard:
    """Arrow keys -> [steering, acceleration]; also reports when the user wants to stop."""

    def __init__(self) -> None:
        self.pygame = importlib.import_module("pygame")
        self.quit = False

    def action(self) -> np.ndarray:
        pygame = self.pygame
        for event in pygame.event.get((pygame.QUIT, pygame.KEYDOWN)):
            if event.type == pygame.QUIT or event.key == pygame.K_ESCAPE:
                self.quit = True
        keys = pygame.key.get_pressed()
        steer = STEER_RAD * (keys[pygame.K_LEFT] - keys[pygame.K_RIGHT])
        accel = ACCEL_MPS2 if keys[pygame.K_UP] else BRAKE_MPS2 if keys[pygame.K_DOWN] else 0.0
        return np.array([steer, accel], dtype=np.float32)


def play(args: argparse.Namespace, case: str) -> tuple[dict, list[np.ndarray]]:
    """Run the episode; returns (summary counts, frames recorded for the video).

    Every frame shown or recorded carries a title (scenario, case, time), a legend of the car
    colours and, for NOTICE_SECONDS after a car leaves the episode, a notice saying which car
    and why (collided, left the road)."""
    module = env_module(args.scenario)
    want_frames = args.render == "human" or args.record is not None
    env = module.parallel_env(render_mode="rgb_array" if want_frames else None)
    env.reset(seed=args.seed, options={"case": case})
    fps = env.metadata["render_fps"]
    legend = legend_entries(args.scenario, list(env.unwrapped.world.roles))
    notices: list[Notice] = []
    notice_steps = max(1, math.ceil(NOTICE_SECONDS * fps))

    def frame(step: int) -> np.ndarray:
        title = f"{args.scenario}, case {case}, seed {args.seed}: t = {step / fps:.1f} s"
        return annotate(env.render(), title, legend, active_notices(notices, step))

    viewer = keyboard = None
    if args.render == "human":
        from carlo_lite import HumanViewer

        viewer = HumanViewer(f"{args.scenario} ({case})", fps=args.fps or fps)
    frames = [frame(0)] if want_frames else []
    removed: dict[str, str] = {}  # agent -> why it left
    steps = 0
    try:
        if viewer is not None:
            viewer.show(frames[-1])
            keyboard = Keyboard() if args.control else None
        with tqdm(total=env.max_cycles, desc=f"play {args.scenario}", unit="step") as bar:
            while env.agents and not (keyboard is not None and keyboard.quit):
                actions = env.unwrapped.expert_actions()
                if keyboard is not None and args.control in actions:
                    actions[args.control] = keyboard.action()
                _, _, terminations, _, infos = env.step(actions)
                steps += 1
                for agent in sorted(a for a, done in terminations.items() if done):
                    if agent not in removed:
                        info = infos.get(agent, {})
                        removed[agent] = removal_reason(info)
                        text = removal_notice(args.scenario, agent, info)
                        notices.append(Notice(text, steps, steps + notice_steps - 1))
                bar.update()
                if want_frames:
                    frames.append(frame(steps))
                    if args.record is None:
                        del frames[:-1]  # only the window needs it: keep the latest frame
                if viewer is not None:
                    viewer.show(frames[-1])
    finally:
        if viewer is not None:
            viewer.close()
        env.close()
    summary = {
        "steps": steps,
        "removed": dict(sorted(removed.items())),
        "cars": len(env.possible_agents),
    }
    return summary, frames if args.record is not None else []


def encode_video(frames: list[np.ndarray], suffix: str, fps: float) -> bytes:
    """The frames (H, W, 3) uint8 as the bytes of a .gif or .mp4 file, encoded in memory: a
    writer that fails on the output file would leave imageio retrying it at exit."""
    import imageio.v3 as iio

    video = np.stack(frames)  # (F, H, W, 3)
    if suffix == ".gif":
        return iio.imwrite("<bytes>", video, extension=".gif", duration=1000.0 / fps, loop=0)
    # H.264 players want sides divisible by 16: pad with the border rather than resize
    pad = [(0, 0), (0, -video.shape[1] % 16), (0, -video.shape[2] % 16), (0, 0)]
    padded = np.pad(video, pad, mode="edge")
    return iio.imwrite("<bytes>", padded, extension=".mp4", fps=fps, codec="libx264")


def write_video(path: Path, frames: list[np.ndarray], fps: float) -> None:
    """Encode the frames and write them to `path` atomically (no partial file on failure)."""
    data = encode_video(frames, path.suffix.lower(), fps)
    with writing(path) as temp:
        temp.write_bytes(data)


def save_video(video: Path, frames: list[np.ndarray], args: argparse.Namespace) -> None:
    """Write the video, exiting 2 with one line (and no file) if it cannot be written; the
    output is checked again first, in case it appeared while the episode played."""
    check_output(video, args.overwrite)
    fps = args.fps or 1.0 / VERSIONS[args.scenario].config().recorded_dt
    try:
        write_video(video, frames, fps)
    except OSError as error:
        fail(f"cannot write {video}: {error.strerror or error}", write_failure_code(error.errno))


def main(argv: list[str] | None = None) -> None:
    args = parse_args(argv)
    case, video = check_args(args)
    try:
        summary, frames = play(args, case)
        if video is not None:
            save_video(video, frames, args)
    except KeyboardInterrupt:
        fail("interrupted; nothing was written", code=INTERRUPTED)
    removed = summary["removed"]
    message = (
        f"{args.scenario} {case} seed {args.seed}: {summary['steps']} steps, "
        f"{len(removed)} of {summary['cars']} cars removed"
        + (f" ({', '.join(f'{a}: {why}' for a, why in removed.items())})" if removed else "")
    )
    if video is not None:
        message += f"; wrote {video} ({len(frames)} frames)"
    print(message)


if __name__ == "__main__":
    run_main(main)
