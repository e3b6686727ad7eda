"""The ``guardrail`` command line."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from guardrail_core.errors import GuardrailError

DEMO_SCENE = "sample"


def _size(text: str) -> tuple[int, int]:
    try:
        width, height = (int(v) for v in text.lower().split("x"))
    except ValueError as exc:
        raise argparse.ArgumentTypeError(
            f"expected WIDTHxHEIGHT, e.g. 1024x768, got {text!r}"
        ) from exc
    if not (64 <= width <= 8192 and 64 <= height <= 8192):
        raise argparse.ArgumentTypeError("image sides must lie within 64..8192 pixels")
    return width, height


def _simulate(args: argparse.Namespace) -> int:
    from guardrail_core.drive import load_drive
    from guardrail_core.drive_summary import describe_drive
    from guardrail_core.synth.scene import load_scene_spec, random_scene_spec
    from guardrail_core.synth.simulate import SimulationOptions, simulate_drive

    if args.scene:
        spec = load_scene_spec(args.scene)
        if args.length is not None:
            print(
                "note: --length is ignored with --scene (the spec sets the drive)", file=sys.stderr
            )
    else:
        spec = random_scene_spec(args.seed, args.length if args.length is not None else 100.0)
    options = SimulationOptions(
        image_every_m=args.image_every, image_size=args.image_size, compress=not args.las
    )
    summary = simulate_drive(
        spec,
        args.out,
        seed=args.seed,
        options=options,
        overwrite=args.overwrite,
        progress=not args.quiet,
    )
    timing = ", ".join(f"{k} {v:.1f} s" for k, v in summary.seconds.items())
    print(f"simulated {summary.length_m:.1f} m in {sum(summary.seconds.values()):.1f} s ({timing})")
    print(describe_drive(load_drive(summary.out)))
    return 0


def _info(args: argparse.Namespace) -> int:
    from guardrail_core.drive import load_drive
    from guardrail_core.drive_summary import describe_drive

    print(describe_drive(load_drive(args.drive)))
    return 0


def _demo(args: argparse.Namespace) -> int:
    from guardrail_core.drive import load_drive
    from guardrail_core.drive_summary import describe_drive
    from guardrail_core.synth.scene import load_scene_spec
    from guardrail_core.synth.simulate import simulate_drive

    out = Path(args.out)
    if (out / "drive.json").is_file() and not args.fresh:
        print(f"the sample drive is already there (--fresh to simulate it again): {out}")
    else:
        simulate_drive(
            load_scene_spec(DEMO_SCENE), out, seed=7, overwrite=True, progress=not args.quiet
        )
        print(f"simulated the sample drive into {out}")
    print(describe_drive(load_drive(out)))
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="guardrail",
        description="Find, reconstruct and review guardrails in mobile-mapping point clouds and images.",
    )
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    sim = sub.add_parser(
        "simulate",
        help="simulate a mapping drive with exact ground truth",
        description="Simulate a mobile-mapping drive (profile laser scanner, cameras, trajectory) "
        "through a random street from --seed, or through the scene of --scene, into the drive folder OUT.",
    )
    sim.add_argument(
        "out", type=Path, help="drive folder to write (must not exist, or use --overwrite)"
    )
    sim.add_argument(
        "--seed", type=int, default=0, help="random seed: same seed, same drive (default 0)"
    )
    sim.add_argument(
        "--length", type=float, default=None, help="metres to drive in a random scene (default 100)"
    )
    sim.add_argument(
        "--scene", help="scene spec YAML (a path, or the name of one in data_samples/scenes)"
    )
    sim.add_argument(
        "--image-every",
        type=float,
        default=5.0,
        metavar="METRES",
        help="camera trigger spacing (default 5)",
    )
    sim.add_argument(
        "--image-size",
        type=_size,
        default=(1024, 768),
        metavar="WxH",
        help="image size (default 1024x768)",
    )
    sim.add_argument(
        "--las", action="store_true", help="write uncompressed points.las instead of points.laz"
    )
    sim.add_argument("--overwrite", action="store_true", help="replace OUT if it exists")
    sim.add_argument("--quiet", action="store_true", help="no progress bars")
    sim.set_defaults(func=_simulate)

    info = sub.add_parser(
        "info",
        help="describe a drive folder",
        description="Validate a drive folder and describe it.",
    )
    info.add_argument("drive", type=Path)
    info.set_defaults(func=_info)

    demo = sub.add_parser(
        "demo",
        help="simulate the sample drive and describe it",
        description="The end-to-end demo: simulate the sample drive "
        "(data_samples/scenes/sample.yaml) and show what is in it.",
    )
    demo.add_argument("--out", type=Path, default=Path("demo_output/sample_drive"))
    demo.add_argument(
        "--fresh", action="store_true", help="simulate again even if the drive exists"
    )
    demo.add_argument("--quiet", action="store_true")
    demo.set_defaults(func=_demo)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return int(args.func(args))
    except GuardrailError as exc:
        print(f"guardrail: error: {type(exc).__name__}: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("guardrail: interrupted; nothing half-written was kept", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
