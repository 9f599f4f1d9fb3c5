r'''camval: validation-first test framework for camera image synthesis

camval renders calibration targets and scenes through the JPL camera models
CAHV, CAHVOR and CAHVORE, recalibrates the images with reference calibrators
and reports how far each recovered parameter lies from the truth.

Each subcommand has its own --help. Errors in the input (bad model files,
unknown cameras, bad options) print one line and exit with status 2.
'''

# Arguments are parsed before any heavy import: every subcommand lives in a
# module of its own (camval/commands/*.py) that imports numpy, mrcal, ... only
# inside its run() function, so `camval --help` is instant.

import argparse
import importlib
import sys

# subcommand name -> module in camval.commands providing add_arguments(parser)
# and run(args) -> exit status. Later work adds entries here.
COMMANDS = {
    "catalogue": "camval.commands.catalogue",
    "render": "camval.commands.render",
    "calibrate": "camval.commands.calibrate",
    "verify": "camval.commands.verify",
    "report": "camval.commands.report",
    "gate": "camval.commands.gate",
    "baseline": "camval.commands.baseline",
    "renderers": "camval.commands.renderers",
    "stereo": "camval.commands.stereo",
    "sweep": "camval.commands.sweep",
    "models": "camval.commands.models",
    "warm-up": "camval.commands.warmup",
}


def _available_commands():
    out = {}
    for name, modname in COMMANDS.items():
        try:
            out[name] = importlib.import_module(modname)
        except ModuleNotFoundError as e:
            if e.name != modname:
                raise
    return out


def build_parser():
    commands = _available_commands()
    parser = argparse.ArgumentParser(
        prog="camval", description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="subcommand", metavar="COMMAND")
    sub.required = True
    for name, mod in commands.items():
        doc = (mod.__doc__ or "").strip()
        p = sub.add_parser(name, help=doc.splitlines()[0] if doc else None,
                           description=doc,
                           formatter_class=argparse.RawDescriptionHelpFormatter)
        mod.add_arguments(p)
        p.set_defaults(_module=mod)
    return parser


def main(argv=None):
    parser = build_parser()
    args = parser.parse_args(argv)
    from reference_models.errors import CamvalError
    try:
        return int(args._module.run(args) or 0)
    except CamvalError as e:
        print(f"camval {args.subcommand}: error: {e}", file=sys.stderr)
        return 2
    except BrokenPipeError:
        return 0


if __name__ == "__main__":
    sys.exit(main())
