#!/usr/bin/env python3
r'''A worked example of an external renderer speaking camval's request protocol

    python examples/external_renderer.py REQUEST.json

camval's "command" renderer (renderers/command.py) writes a request directory
(camera model as a JPL file, the board and its pose as scene.json, image size
and sampling in request.json) and runs this program with the path of
request.json. The program renders and writes the image where the request says
(a 16-bit grey PNG, or .npy float32), then exits 0. Anything it prints to
stderr is shown to the user when it fails.

This example renders with camval's own exact ray caster, so a campaign run
through it must give the same records as the built-in "raycast" renderer:

    camval campaign ... --renderer command \
        --renderer-option 'command=["python", "examples/external_renderer.py"]'

A simulator team replaces the middle of main() by a call into its renderer.
Options (request.json "options"): "fail": exit 3 with a message (used by the
tests of the failure paths); "wrong_size": write a 1x1 image.
'''

import os
import sys


def main(argv):
    if len(argv) != 2 or argv[1] in ("-h", "--help"):
        print(__doc__, file=sys.stderr)
        return 2
    # run from anywhere: camval's repository is this file's parent directory
    sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    import numpy as np

    from renderers.command import read_request, write_image
    from renderers.raycast import RaycastRenderer

    req = read_request(argv[1])
    if req.settings.options.get("fail"):
        print(f"external_renderer: asked to fail ({req.settings.options['fail']})",
              file=sys.stderr)
        return 3
    result = RaycastRenderer().render(req.model, req.pattern, req.Rt_cam_board, req.settings)
    image = result.image
    if req.settings.options.get("wrong_size"):
        image = np.zeros((1, 1))
    write_image(req.output, image)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
