r'''The `--command` / `--setup` options of the commands that can render through an external
program (`camval render`, `camval stereo`): defined and read in one place'''


def add_arguments(parser):
    parser.add_argument("--command", default=None, metavar="'PROGRAM ARGS...'",
                        help="--renderer command: the external renderer to run (split as a "
                             "shell would)")
    parser.add_argument("--setup", action="append", default=[], metavar="KEY=VALUE",
                        help="--renderer command: a setup value (timeout=60, persistent=true, "
                             "output_format=npy, mode=rays, env={...}); repeatable")


def renderer_options(args, error=None):
    r'''{} for a built-in renderer; the command renderer's setup from --command/--setup;
`error` (default CamvalError) when they are given to another renderer'''
    if args.renderer == "command":
        from renderers.command import setup_from_cli
        return setup_from_cli(args.command, args.setup)
    if args.command or args.setup:
        if error is None:
            from reference_models.errors import CamvalError as error
        raise error("--command and --setup are for --renderer command")
    return {}
