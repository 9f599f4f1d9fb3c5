r'''List, show and export the cameras of the catalogue

  camval catalogue list [--overlay F]        the 22 paper slots and the extras
  camval catalogue show ID                   one model with its decomposition
  camval catalogue export ID --format cahvor|cameramodel -o FILE [--force]

ID is a slot id (1-22), an extra's name (e.g. SuperCam) or a model file
(.cahv/.cahvor/.cahvore, PDS3 .LBL/.IMG, mrcal .cameramodel). An overlay TOML
points slots at model files of one's own:

  [[replace]]
  id = 15
  file = "models/navcam_left.cahvor"     # relative to the overlay file

(see reference_models/catalogue.py for the whole format). mrcal cannot
represent theta != 90 deg; `export --format cameramodel` needs --orthogonalise
to export such a model's theta = 90 version.
'''

import sys


def add_arguments(parser):
    parser.add_argument("--overlay", action="append", metavar="F",
                        help="overlay TOML replacing or adding cameras (repeatable)")
    sub = parser.add_subparsers(dest="action", metavar="ACTION")
    sub.required = True
    p = sub.add_parser("list", help="table of all cameras")
    p.add_argument("--overlay", action="append", metavar="F", dest="overlay_sub",
                   help="overlay TOML replacing or adding cameras (repeatable)")
    p = sub.add_parser("show", help="one model with its decomposition")
    p.add_argument("id", metavar="ID", help="slot id, extra name or model file")
    p.add_argument("--overlay", action="append", metavar="F", dest="overlay_sub")
    p = sub.add_parser("export", help="write a model as a JPL .cahvor or a mrcal .cameramodel")
    p.add_argument("id", metavar="ID", help="slot id, extra name or model file")
    p.add_argument("--format", required=True, choices=("cahvor", "cameramodel"))
    p.add_argument("-o", "--output", required=True, metavar="FILE")
    p.add_argument("--force", action="store_true", help="overwrite FILE if it exists")
    p.add_argument("--orthogonalise", action="store_true",
                   help="for cameramodel: export the theta = 90 version of a model")
    p.add_argument("--overlay", action="append", metavar="F", dest="overlay_sub")


def run(args):
    from reference_models.catalogue import load_catalogue

    overlays = (args.overlay or []) + (getattr(args, "overlay_sub", None) or [])
    cat = load_catalogue(overlay=overlays or None)
    if args.action == "list":
        return _list(cat)
    entry = cat.get(args.id)
    if args.action == "show":
        return _show(entry)
    return _export(entry, args)


def _vec(v):
    return " ".join(f"{x:.9g}" for x in v)


def _rows(cat):
    from reference_models.catalogue import field_of_view_deg

    rows = []
    for e in cat:
        m = e.model
        hfov, _ = field_of_view_deg(m)
        ident = str(e.id) if e.id is not None else e.name
        model = m.family
        if m.family == "CAHVORE":
            model += f" T{m.model_type} L={m.linearity:g}"
        status = e.status + (" (overlay)" if e.replaces is not None else "")
        rows.append((ident, e.rover or "", e.role or "", e.side or "", status, model,
                     f"{m.width}x{m.height}", f"{hfov:.2f}",
                     f"{m.photogrammetric().theta_deg:.4f}" + (" M" if m.mirrored else "")))
    return rows


HEADER = ("id", "rover", "role", "side", "status", "model", "size", "hfov deg", "theta deg")


def _list(cat):
    rows = _rows(cat)
    if sys.stdout.isatty():
        from rich.console import Console
        from rich.table import Table

        t = Table(*HEADER)
        for r in rows:
            t.add_row(*r)
        Console().print(t)
    else:
        widths = [max(len(h), *(len(r[i]) for r in rows)) for i, h in enumerate(HEADER)]
        print("  ".join(h.ljust(w) for h, w in zip(HEADER, widths, strict=True)).rstrip())
        for r in rows:
            print("  ".join(c.ljust(w) for c, w in zip(r, widths, strict=True)).rstrip())
    if any(r[-1].endswith(" M") for r in rows):
        print("M: mirrored (H' x V' points against A)")
    return 0


def _show(e):
    import math

    from reference_models.catalogue import field_of_view_deg
    from reference_models.jpl_files import jpl_theta

    m = e.model
    ph = m.photogrammetric()
    hfov, vfov = field_of_view_deg(m)
    out = [f"camera      {e.key}: {e.name}"]
    for label, value in (("rover", e.rover), ("role", e.role), ("side", e.side),
                         ("status", e.status), ("source", e.source),
                         ("stands in", e.stands_in), ("derivation", e.derivation),
                         ("frame", e.frame)):
        if value:
            out.append(f"{label:<12}{value}")
    for k, v in e.provenance.items():
        if k not in ("id", "name", "rover", "role", "side", "status", "source", "stands_in",
                     "derivation", "frame"):
            out.append(f"{k:<12}{v}")
    if e.replaces is not None:
        out.append(f"{'replaces':<12}{e.replaces.status} model from {e.replaces.source}")
    model = m.family
    if m.family == "CAHVORE":
        model += f" (type {m.model_type}, linearity {m.linearity!r})"
    out += [f"model       {model}", f"size        {m.width} x {m.height}"]
    for name in ("C", "A", "H", "V", "O", "R", "E"):
        if hasattr(m, name) and getattr(m, name) is not None:
            out.append(f"{name:<12}{_vec(getattr(m, name))}")
    out += [
        "decomposition",
        f"  Hc        {ph.Hc:.9g} px",
        f"  Vc        {ph.Vc:.9g} px",
        f"  Hs        {ph.Hs:.9g} px",
        f"  Vs        {ph.Vs:.9g} px",
        f"  theta     {ph.theta_deg:.9g} deg (JPL signed: {math.degrees(jpl_theta(m)):.9g} deg)",
        f"  H'        {_vec(ph.Hp)}",
        f"  V'        {_vec(ph.Vp)}",
        f"  mirrored  {'yes' if m.mirrored else 'no'}",
        f"  central   {'yes' if m.is_central else 'no (E != 0: the entrance pupil moves)'}",
        f"  FOV       {hfov:.4f} x {vfov:.4f} deg",
    ]
    print("\n".join(out))
    return 0


def _export(e, args):
    import os

    from reference_models.jpl_files import OutputExistsError, write_model

    if os.path.exists(args.output) and not args.force:
        raise OutputExistsError(f"'{args.output}' exists; not overwriting it without --force")
    if args.format == "cahvor":
        write_model(e.model, args.output, overwrite=True,
                    note=f"camval catalogue {e.key}: {e.name}\nsource: {e.source}")
    else:
        from reference_models.mrcal_convert import to_mrcal

        cm = to_mrcal(e.model, orthogonalise=args.orthogonalise)
        cm.write(args.output, note=f"camval catalogue {e.key}: {e.name}; source: {e.source}")
    print(f"wrote {args.output}")
    return 0
