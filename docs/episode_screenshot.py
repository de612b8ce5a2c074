"""Make docs/episode.png: a rule-based episode of the default config in the rerun viewer.

Needs a running headless viewer with a renderer (on a machine without a GPU:
``apt-get install mesa-vulkan-drivers``)::

    rerun --headless --renderer vulkan --window-size 1600x900 &
    python docs/episode_screenshot.py   # then stop the viewer

Episode 0 of the evaluation key (``drqn-jax replay --agent rule-based
--episodes 1``), with the world view zoomed on the ego 7 steps (0.7 s) before the
episode ends (``--step`` chooses another).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import drqn_jax
from drqn_jax.config import load_config
from drqn_jax.interop import episode_record, recording


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--step", type=int, help="time cursor (default: 7 before the end)")
    parser.add_argument("--rrd", default="/tmp/drqn_jax_episode.rrd", help="recording to write")
    parser.add_argument("--out", default="docs/episode.png", help="screenshot to write")
    args = parser.parse_args()

    from rerun.experimental import ViewerClient

    config = load_config("default")
    env, params = config.make_env()
    _, eval_key = config.keys()
    agent = drqn_jax.rule_based_agent(config.rule_based_params())
    record = episode_record.collect_episodes(agent, eval_key, 1, env, params)
    if args.step is None:
        args.step = max(0, int(record.length[0]) - 7)
    s = float(record.state.ego.s[0, args.step])
    blueprint = recording.episode_blueprint(1, False, env, params, x_range=(s - 15.0, s + 45.0))
    recording.write_episodes(args.rrd, record, env, params, blueprint=blueprint)

    viewer = ViewerClient.connect()
    viewer.open(str(Path(args.rrd).resolve()))
    while viewer.get_state().loading:
        time.sleep(0.5)
    viewer.set_time("step", sequence=args.step, play_state="paused")
    time.sleep(2.0)  # let it paint the new time
    viewer.save_screenshot(str(Path(args.out).resolve()))


if __name__ == "__main__":
    main()
