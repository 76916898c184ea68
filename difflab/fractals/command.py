"""`difflab fractal KIND -o out.png`: draw a curve or render a fractal set."""

from __future__ import annotations

from pathlib import Path


def run_fractal(args) -> int:
    from .figures import fractal_figure

    options = {"order": args.order} if args.order is not None else {}
    if args.kind not in ("koch", "peano", "hilbert", "cantor"):
        options.update(seed=args.seed, hurst=args.hurst, max_iter=args.max_iter, device=args.device)
        if args.kind in ("mandelbrot", "julia", "mandelbulb"):
            for key in ("order", "seed", "hurst"):
                options.pop(key, None)
        else:
            options.pop("max_iter")
    caption = fractal_figure(args.kind, Path(args.output), args.width, args.height, **options)
    print(f"wrote {args.output}: {caption}")
    return 0


def add_parser(sub) -> None:
    from .figures import KINDS

    p = sub.add_parser("fractal", help="draw a fractal curve or render a fractal set")
    p.add_argument("kind", choices=KINDS)
    p.add_argument("-o", "--output", required=True, help="output PNG")
    p.add_argument("--order", type=int, help="iterations / order / depth / terrain level")
    p.add_argument("--width", type=int, default=640)
    p.add_argument("--height", type=int, default=480)
    p.add_argument("--seed", type=int, default=0, help="terrain seed")
    p.add_argument("--hurst", type=float, default=0.8, help="terrain roughness (Hurst exponent in (0, 1))")
    p.add_argument("--max-iter", type=int, default=256, help="escape-time iterations")
    p.add_argument("--device", default="cpu")
    p.set_defaults(func=run_fractal)
