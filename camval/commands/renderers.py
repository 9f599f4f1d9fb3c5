r'''List the renderers camval knows: built-in ones and entry-point plugins

    camval renderers list [--check]

Built-in renderers are listed with their module; plugins are Python packages
that declare an entry point in the group "camval.renderers". --check
constructs each renderer and prints its version, or why it cannot run here
(a missing backend names its fix).
'''


def add_arguments(parser):
    sub = parser.add_subparsers(dest="action", metavar="ACTION")
    sub.required = True
    p = sub.add_parser("list", help="list the known renderers")
    p.add_argument("--check", action="store_true",
                   help="construct each renderer: print its version or why it is unavailable")


def run(args):
    from reference_models.errors import CamvalError
    from renderers.base import get_renderer, known_renderers

    known = known_renderers()
    width = max(len(n) for n in known)
    for name, source in sorted(known.items()):
        line = f"{name:<{width}}  {source}"
        if args.check:
            try:
                r = get_renderer(name)
                status = f"ok: {r.version()}"
            except CamvalError as e:
                status = f"unavailable: {e}"
            except Exception as e:   # a broken plugin must not hide the others
                status = f"broken: {type(e).__name__}: {e}"
            line += f"\n{'':<{width}}  {status}"
        print(line)
    return 0
