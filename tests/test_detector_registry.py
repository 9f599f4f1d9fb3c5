r'''The detector registry: built-in kinds, a plugin under the entry-point group
"camval.detectors", and the error for a kind without a detector

The plugin is a real installed distribution as importlib.metadata sees one: a
*.dist-info directory with METADATA and entry_points.txt on sys.path, and the
module it names (as tests/test_plugins.py does for renderers). It detects the
made-up kind "wrapped_dots": a dot board wrapped in a target of that kind.
'''

import dataclasses

import numpy as np
import pytest
from targets_render import pinhole, render

from targets.boards import load_target
from targets.detect import (
    BUILTIN_DETECTORS,
    ENTRY_POINT_GROUP,
    Detector,
    UnknownDetectorError,
    detect,
    get_detector,
    known_detectors,
)
from targets.detection import Detection, DetectionInputError
from targets.poses import plan_poses

PLUGIN_MODULE = '''
import dataclasses

from targets.detect_dots import detect_dots


def detect_wrapped_dots(image, target, **options):
    det = detect_dots(image, target.board, **options)
    return dataclasses.replace(det, detector="wrapped_dots")
'''


@dataclasses.dataclass(frozen=True)
class WrappedDots:
    board: object
    kind: str = "wrapped_dots"

    @property
    def Npoints(self):
        return self.board.Npoints


@pytest.fixture
def plugin_on_path(tmp_path, monkeypatch):
    (tmp_path / "camval_test_detector.py").write_text(PLUGIN_MODULE)
    info = tmp_path / "camval_test_detector-0.1.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: camval-test-detector\n"
                                   "Version: 0.1\n")
    (info / "entry_points.txt").write_text(
        f"[{ENTRY_POINT_GROUP}]\nwrapped_dots = camval_test_detector:detect_wrapped_dots\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    yield
    import sys
    sys.modules.pop("camval_test_detector", None)


def _dots_image():
    m = pinhole(320, 240, 220.0)
    t = load_target("dots")
    return render(m, t.pattern(), plan_poses(m, t)[0], K=4), t


def test_built_in_kinds_are_the_built_in_detectors():
    known = known_detectors()
    assert list(known)[:3] == ["dots", "apriltag", "chessboard"]
    for kind, spec in BUILTIN_DETECTORS.items():
        assert known[kind] == f"built-in ({spec})"
        assert isinstance(get_detector(kind), Detector)


def test_plugin_is_listed_beside_the_built_in_detectors(plugin_on_path):
    known = known_detectors()
    assert known["dots"].startswith("built-in")
    assert known["wrapped_dots"] == ("plugin (camval_test_detector:detect_wrapped_dots, "
                                     "package camval-test-detector)")


def test_plugin_detects_exactly_what_the_built_in_detector_detects(plugin_on_path):
    img, dots = _dots_image()
    a = detect(img, WrappedDots(dots))
    b = detect(img, dots)
    assert isinstance(a, Detection) and a.detector == "wrapped_dots"
    assert b.status == "ok" and b.n_found == b.n_expected
    assert a.status == b.status and a.n_found == b.n_found
    np.testing.assert_array_equal(a.q, b.q)


def test_without_the_plugin_the_kind_has_no_detector():
    assert "wrapped_dots" not in known_detectors()
    with pytest.raises(UnknownDetectorError,
                       match="no detector for target kind 'wrapped_dots'; known kinds: "
                             "dots, apriltag, chessboard"):
        detect(np.zeros((10, 10)), WrappedDots(None))
    # a kind without a detector is bad input, as an image that is not one
    assert issubclass(UnknownDetectorError, DetectionInputError)


def test_detectors_import_no_registry():
    r'''The detectors build their results from targets.detection, not from the registry
that imports them (no import cycle)'''
    import ast
    import importlib.util
    for spec in BUILTIN_DETECTORS.values():
        path = importlib.util.find_spec(spec.split(":")[0]).origin
        with open(path) as f:
            tree = ast.parse(f.read())
        imported = {node.module for node in ast.walk(tree) if isinstance(node, ast.ImportFrom)}
        assert "detect" not in imported and "targets.detect" not in imported, path


PLUGIN_FOR_FILE = '''
import dataclasses

from targets.detect_dots import detect_dots


def detect_my_dots(image, target, **options):
    return dataclasses.replace(detect_dots(image, target, **options), detector="my_dots")
'''


@pytest.fixture
def my_dots_plugin(tmp_path, monkeypatch):
    (tmp_path / "camval_test_my_dots.py").write_text(PLUGIN_FOR_FILE)
    info = tmp_path / "camval_test_my_dots-0.1.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: camval-test-my-dots\n"
                                   "Version: 0.1\n")
    (info / "entry_points.txt").write_text(
        f"[{ENTRY_POINT_GROUP}]\nmy_dots = camval_test_my_dots:detect_my_dots\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    yield
    import sys
    sys.modules.pop("camval_test_my_dots", None)


def _dots_file_with_detector(tmp_path, detector):
    import tomllib

    from targets.boards import known_targets
    with open(known_targets()["dots"], "rb") as f:
        spec = tomllib.load(f)
    text = (known_targets()["dots"].read_text()
            .replace('name = "dots"', 'name = "my_dots_board"')
            .replace('kind = "dots"', f'kind = "dots"\ndetector = "{detector}"'))
    path = tmp_path / "my_dots_board.toml"
    path.write_text(text)
    assert tomllib.loads(text)["detector"] == detector and spec["kind"] == "dots"
    return path


def test_a_target_file_names_a_plugin_detector(tmp_path, my_dots_plugin):
    r'''kind = "dots" (the geometry) and detector = "my_dots" (the plug-in): detect() uses
the plug-in, on the same points the built-in detector finds'''
    path = _dots_file_with_detector(tmp_path, "my_dots")
    board = load_target(path)
    assert board.kind == "dots" and board.detector == "my_dots"
    img, dots = _dots_image()
    a = detect(img, board)
    b = detect(img, dots)
    assert a.detector == "my_dots" and b.detector != "my_dots"
    assert a.status == "ok" and a.n_found == b.n_found == dots.Npoints
    np.testing.assert_array_equal(a.q, b.q)


def test_a_campaign_runs_a_plugin_detector_through_its_target_file(tmp_path, my_dots_plugin):
    r'''The campaign's target list is targets.boards' (built-in names or files); the file
carries the plug-in detector into the job's detection stage'''
    from harness.campaign import load_campaign
    from harness.jobs import expand_jobs
    from harness.stages import cached_target
    path = _dots_file_with_detector(tmp_path, "my_dots")
    camp = tmp_path / "c.toml"
    camp.write_text(f'cameras = [15]\nmodels = ["CAHVOR"]\ntargets = ["dots", "{path}"]\n')
    jobs = expand_jobs(load_campaign(camp))
    assert [j.target for j in jobs] == ["dots", str(path)]
    assert cached_target(jobs[1].target).detector == "my_dots"


def test_a_target_file_naming_an_unregistered_detector_is_refused(tmp_path):
    from targets.boards import TargetError
    path = _dots_file_with_detector(tmp_path, "my_dots")
    with pytest.raises(TargetError, match=r"detector = 'my_dots' is not registered; known "
                                          r"detectors: dots, apriltag, chessboard"):
        load_target(path)


def test_built_in_targets_name_their_kinds_detector():
    from targets.boards import TARGET_KINDS, known_targets
    assert set(known_targets()) == set(TARGET_KINDS) == set(BUILTIN_DETECTORS)
    for name in known_targets():
        assert load_target(name).detector == name
