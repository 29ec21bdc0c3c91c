"""The ``simn-sim`` command line.

simn-sim demo --out runs/demo            one headless episode: episodes.jsonl, config.json, .rrd
simn-sim episodes --out F --n 20 ...     sample a fixed, seeded episode set (JSON data)
simn-sim compare BASE.jsonl NEW.jsonl    regression check of two batches (non-zero on regression)
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

DEFAULT_AGENT = "simn"


def _env_cfg(args: argparse.Namespace) -> dict[str, Any]:
    cfg: dict[str, Any] = {}
    if getattr(args, "config", None):
        import yaml

        from simn_sim.config import ConfigError

        try:
            cfg = yaml.safe_load(Path(args.config).read_text()) or {}
        except (OSError, yaml.YAMLError) as e:
            raise ConfigError(f"cannot read config file {args.config}: {e}") from e
        if not isinstance(cfg, dict):
            raise ConfigError(f"config file {args.config} must hold a mapping")
    for key in ("width", "height", "layout_seed", "max_episode_steps"):
        v = getattr(args, key, None)
        if v is not None:
            cfg[key] = v
    if getattr(args, "noise", None):
        cfg["depth_noise"] = {**cfg.get("depth_noise", {}), "model": args.noise}
    return cfg


def _resolve_agent(name: str | None) -> str:
    from simn_sim.agents import agent_names

    names = agent_names()
    if name is None:
        return DEFAULT_AGENT if DEFAULT_AGENT in names else "oracle"
    if name not in names:
        raise ValueError(f"unknown agent {name!r}; valid agents: {names}")
    return name


def _resolved_agent_config(agent: str, env: Any) -> dict[str, Any]:
    """Every config value of ``agent`` (defaults included), for config.json."""
    from simn_sim.agents import make_agent

    return make_agent(agent, env, {}).config_dict()


def cmd_demo(args: argparse.Namespace) -> int:
    import gymnasium as gym
    from tqdm import tqdm

    from simn_sim.env.episodes import EpisodeSet
    from simn_sim.experiments.runner import run_episode, write_json

    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise ValueError(f"--out {out} exists and is not a directory (demo writes a folder)")
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as e:  # e.g. a parent is a file, or no permission
        raise ValueError(f"cannot create the --out folder {out}: {e.strerror or e}") from e
    env_cfg = _env_cfg(args)
    agent = _resolve_agent(args.agent)
    episode = None
    env_id = args.env or "SimnOffice-v0"
    if args.episode_file:
        eset = EpisodeSet.load(args.episode_file)
        episode = eset.episodes[args.episode_index].to_dict()
        env_id = args.env or eset.env_id  # the file's env id unless --env is given
    args.env = env_id
    env = gym.make(args.env, config=env_cfg)
    resolved = {
        "env_id": args.env,
        "env": env.unwrapped.cfg.to_dict(),
        "agent": agent,
        "agent_config": _resolved_agent_config(agent, env.unwrapped),
        "seed": args.seed,
        "episode": episode,
    }
    rrd = None if args.no_rerun else out / "episode.rrd"
    with tqdm(
        total=env.unwrapped.cfg.max_episode_steps, desc=f"demo ({agent})", unit="step"
    ) as bar:
        rec = run_episode(
            args.env,
            env.unwrapped.cfg,
            agent,
            {},
            episode=episode,
            seed=args.seed,
            rerun_path=rrd,
            progress=bar,
            env=env,
            image_every=args.image_every,
        )
    env.close()
    write_json(out / "config.json", resolved)
    with open(out / "episodes.jsonl", "w") as f:
        f.write(json.dumps(rec, default=str) + "\n")
    if rec["error"]:
        print(rec["error"], file=sys.stderr)
        return 1
    print(
        f"{rec['episode_id']}: termination={rec['termination']} success={rec['success']} "
        f"spl={rec['spl']:.3f} path={rec['path_length_m']:.2f} m geodesic={rec['geodesic_distance_m']:.2f} m "
        f"collisions={rec['collisions']} steps={rec['steps']}"
    )
    print(f"wrote {out / 'episodes.jsonl'}, {out / 'config.json'}" + (f", {rrd}" if rrd else ""))
    return 0


def cmd_episodes(args: argparse.Namespace) -> int:
    import gymnasium as gym
    from tqdm import tqdm

    from simn_sim.env.episodes import EpisodeSet, EpisodeSpec

    layouts = [None if s < 0 else s for s in args.layouts]
    if args.pool:
        return _episodes_from_pool(args, layouts)
    if args.min_traps or args.people_clearance:
        raise ValueError("--min-traps and --people-clearance need --pool")
    eps: list[EpisodeSpec] = []
    with tqdm(total=args.n * len(layouts), desc="sampling episodes") as bar:
        for lay in layouts:
            env = gym.make(
                args.env,
                config={
                    "width": 64,
                    "height": 48,
                    "layout_seed": lay,
                    "min_geodesic": args.min_geodesic,
                    "max_geodesic": args.max_geodesic,
                },
            )
            for i in range(args.n):
                seed = args.seed * 10007 + (0 if lay is None else lay + 1) * 1000 + i
                _, info = env.reset(seed=seed)
                spec = info["episode_spec"]
                tag = "ref" if lay is None else f"L{lay}"
                eps.append(
                    EpisodeSpec(
                        f"{args.prefix}-{tag}-{i:03d}",
                        lay,
                        tuple(spec["start"]),
                        tuple(spec["goal"]),
                        seed,
                    )
                )
                bar.update(1)
            env.close()
    EpisodeSet(args.env, eps).save(args.out)
    print(f"wrote {len(eps)} episodes to {args.out}")
    return 0


def _episodes_from_pool(args: argparse.Namespace, layouts: list[int | None]) -> int:
    """``--pool K``: choose ``--n`` per layout from K candidates (simn_sim.env.episode_sets)."""
    from tqdm import tqdm

    from simn_sim.env.episode_sets import TRAP_TAG, build_episode_set
    from simn_sim.experiments.batch_config import BatchError, resolve_env_config

    try:
        clearance = float(resolve_env_config(args.env, {})["start_clearance"])
    except BatchError as e:
        raise ValueError(str(e)) from e
    with tqdm(total=len(layouts), desc=f"sampling {args.pool} candidates per layout") as bar:
        eset = build_episode_set(
            args.env,
            layouts,
            n=args.n,
            seed=args.seed,
            prefix=args.prefix,
            min_geodesic=args.min_geodesic,
            max_geodesic=args.max_geodesic,
            pool=args.pool,
            bins=args.geodesic_bins,
            min_traps=args.min_traps,
            start_clearance=clearance,
            people_clearance=args.people_clearance,
            progress=bar.update,
        )
    eset.save(args.out)
    n_traps = sum(TRAP_TAG in e.tags for e in eset.episodes)
    print(f"wrote {len(eset.episodes)} episodes ({n_traps} traps) to {args.out}")
    return 0


def _passthrough(sub, name: str, help_: str, target: str) -> None:
    """A sub-command whose arguments are parsed by ``target`` (``module:function(argv) -> int``)."""
    p = sub.add_parser(name, help=help_, add_help=False)
    p.add_argument("rest", nargs=argparse.REMAINDER)

    def run(args: argparse.Namespace) -> int:
        import importlib

        mod, fn = target.split(":")
        return getattr(importlib.import_module(mod), fn)(args.rest)

    p.set_defaults(func=run)


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="simn-sim", description="SIMN navigation testbed")
    sub = p.add_subparsers(dest="cmd", required=True)

    d = sub.add_parser(
        "demo", help="run one headless episode, write metrics, config and a rerun recording"
    )
    d.add_argument("--out", required=True)
    d.add_argument(
        "--env", default=None, help="env id (default: the episode file's, else SimnOffice-v0)"
    )
    d.add_argument("--agent", default=None, help="simn (default), simn_points, rrtstar or oracle")
    d.add_argument("--seed", type=int, default=0)
    d.add_argument("--episode-file", default=None)
    d.add_argument("--episode-index", type=int, default=0)
    d.add_argument("--config", default=None, help="YAML file of env config values")
    d.add_argument("--width", type=int)
    d.add_argument("--height", type=int)
    d.add_argument("--layout-seed", dest="layout_seed", type=int)
    d.add_argument("--max-episode-steps", dest="max_episode_steps", type=int)
    d.add_argument("--noise", choices=["none", "d435i"])
    d.add_argument("--no-rerun", action="store_true")
    d.add_argument("--image-every", type=int, default=2, help="log camera images every n-th step")
    d.set_defaults(func=cmd_demo)

    e = sub.add_parser("episodes", help="sample a fixed, seeded episode set")
    e.add_argument("--out", required=True)
    e.add_argument("--env", default="SimnOffice-v0")
    e.add_argument("--n", type=int, default=10, help="episodes per layout")
    e.add_argument(
        "--layouts",
        type=int,
        nargs="+",
        default=[-1],
        help="layout seeds; -1 is the reference office",
    )
    e.add_argument("--seed", type=int, default=0)
    e.add_argument("--prefix", default="ep")
    e.add_argument("--min-geodesic", type=float, default=3.0)
    e.add_argument("--max-geodesic", type=float, default=12.0)
    e.add_argument(
        "--pool",
        type=int,
        default=0,
        help="draw K candidates per layout by the env sampler's rules and choose --n of them, "
        "spread over the geodesic range, trap episodes tagged (0: take n env samples as drawn)",
    )
    e.add_argument(
        "--geodesic-bins", type=int, default=4, help="with --pool: equal-width geodesic bins"
    )
    e.add_argument(
        "--min-traps",
        type=int,
        default=0,
        help="with --pool: at least this many trap episodes in all (simn_sim.env.traps)",
    )
    e.add_argument(
        "--people-clearance",
        type=float,
        default=0.0,
        help="with --pool: move an episode's seed until no person spawns within this many "
        "metres of the start (dynamic office)",
    )
    e.set_defaults(func=cmd_episodes)

    _passthrough(
        sub,
        "compare",
        "compare two episodes.jsonl files (regression gate)",
        "simn_sim.experiments.compare:main",
    )
    _passthrough(
        sub,
        "batch",
        "run a batch of episodes (local process pool or Ray)",
        "simn_sim.experiments.batch:batch_main",
    )
    _passthrough(
        sub, "record", "record a TUM RGB-D sequence from the env", "simn_sim.slam.cli:record_main"
    )
    _passthrough(
        sub, "slam", "run the SIMN front-end on a TUM RGB-D folder", "simn_sim.slam.cli:slam_main"
    )
    return p


PASSTHROUGH = {
    "compare": "simn_sim.experiments.compare:main",
    "batch": "simn_sim.experiments.batch:batch_main",
    "record": "simn_sim.slam.cli:record_main",
    "slam": "simn_sim.slam.cli:slam_main",
}


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    if argv and argv[0] in PASSTHROUGH:  # these parse their own arguments (incl. --help)
        import importlib

        mod, fn = PASSTHROUGH[argv[0]].split(":")
        return int(getattr(importlib.import_module(mod), fn)(argv[1:]) or 0)
    args = build_parser().parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except (ValueError, FileNotFoundError) as e:
        print(f"simn-sim {args.cmd}: error: {e}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
