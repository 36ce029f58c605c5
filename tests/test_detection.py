"""Yolo-Fastest from darknet files: the PyTorch network against an independent numpy reference, the OpenCV
runtime against PyTorch, the ONNX cache, and the person."""

import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
from numpy.lib.stride_tricks import sliding_window_view

from osslam.errors import InputError
from osslam.frontend.detection import onnx_export
from osslam.frontend.detection.darknet_cfg import parse_cfg
from osslam.frontend.detection.yolo import YoloFastest

from conftest import MODELS

COCO = MODELS / "yolo-fastest-1.1"
BODY = MODELS / "yolo-fastest-1.1-body"
PERSON = MODELS / "samples" / "person.jpg"

COCO_FILES = (COCO / "yolo-fastest-1.1.cfg", COCO / "yolo-fastest-1.1.weights")

pytestmark = pytest.mark.skipif(not (COCO / "yolo-fastest-1.1.weights").is_file(), reason=f"{COCO} not present")


@pytest.fixture
def empty_onnx_cache(tmp_path, monkeypatch) -> Path:
    """A cache folder of the test's own, not yet created."""
    folder = tmp_path / "onnx"
    monkeypatch.setenv(onnx_export.ENV_VAR, str(folder))
    return folder


def _reference_forward(cfg: Path, weights: Path, image: np.ndarray) -> list[np.ndarray]:
    """Darknet's forward pass written plainly in numpy, reading the files on its own."""
    sections = []
    for line in cfg.read_text().splitlines():
        line = line.split("#")[0].strip()
        if line.startswith("["):
            sections.append({"type": line[1:-1]})
        elif "=" in line:
            k, v = line.split("=", 1)
            sections[-1][k.strip()] = v.strip()
    raw = weights.read_bytes()
    major, minor = np.frombuffer(raw[:8], np.int32)
    floats = np.frombuffer(raw[12 + (8 if major * 10 + minor >= 2 else 4):], np.float32)
    pos = 0
    x = image.astype(np.float64)  # (C, H, W)
    outs, heads = [], []
    for s in sections[1:]:
        t = s["type"]
        if t == "convolutional":
            f, k = int(s["filters"]), int(s["size"])
            g, st = int(s.get("groups", 1)), int(s.get("stride", 1))
            c = x.shape[0]
            n_w = f * (c // g) * k * k
            if s.get("batch_normalize") == "1":
                b, sc, mu, var = (floats[pos + i * f : pos + (i + 1) * f] for i in range(4))
                pos += 4 * f
            else:
                b, sc, mu, var = floats[pos : pos + f], None, None, None
                pos += f
            w = floats[pos : pos + n_w].reshape(f, c // g, k, k).astype(np.float64)
            pos += n_w
            p = k // 2 if s.get("pad") == "1" else 0
            xp = np.pad(x, ((0, 0), (p, p), (p, p)))
            win = sliding_window_view(xp, (k, k), axis=(1, 2))[:, ::st, ::st]  # (C, H', W', k, k)
            cg, fg = c // g, f // g
            y = np.concatenate([np.einsum("chwij,fcij->fhw", win[i * cg : (i + 1) * cg], w[i * fg : (i + 1) * fg])
                                for i in range(g)])
            if sc is not None:
                y = (y - mu[:, None, None]) / np.sqrt(var[:, None, None] + 1e-5) * sc[:, None, None]
            y = y + b[:, None, None]
            x = np.where(y > 0, y, 0.1 * y) if s.get("activation") == "leaky" else y
        elif t == "maxpool":
            k = int(s["size"])
            xp = np.pad(x, ((0, 0), (k // 2, k // 2), (k // 2, k // 2)), constant_values=-np.inf)
            x = sliding_window_view(xp, (k, k), axis=(1, 2)).max(axis=(3, 4))
        elif t == "route":
            idx = [int(v) for v in s["layers"].split(",")]
            x = np.concatenate([outs[i if i >= 0 else len(outs) + i] for i in idx])
        elif t == "shortcut":
            x = x + outs[len(outs) + int(s["from"])]
        elif t == "upsample":
            x = x.repeat(2, axis=1).repeat(2, axis=2)
        elif t == "yolo":
            heads.append(x)
        outs.append(x)
    assert pos == len(floats)
    return heads


def test_pytorch_network_matches_the_numpy_reference():
    det = YoloFastest(*COCO_FILES, ["x"] * 80, runtime="torch")
    rng = np.random.default_rng(0)
    image = (rng.random((320, 320, 3)) * 255).astype(np.uint8)
    ours = [h[0] for h in det.raw(image)]
    ref = _reference_forward(COCO / "yolo-fastest-1.1.cfg", COCO / "yolo-fastest-1.1.weights",
                             image.transpose(2, 0, 1) / 255.0)
    assert [o.shape for o in ours] == [r.shape for r in ref] == [(255, 10, 10), (255, 20, 20)]
    for o, r in zip(ours, ref):
        assert np.abs(o - r).max() < 1e-3 * max(1.0, np.abs(r).max())


@pytest.mark.parametrize("runtime", ["opencv", "torch"])
@pytest.mark.parametrize("folder, cfg, names", [(COCO, "yolo-fastest-1.1", "coco.names"),
                                                (BODY, "yolo-fastest-1.1_body", "body.names")])
def test_finds_the_person_in_the_sample_photo(folder, cfg, names, runtime):
    det = YoloFastest(folder / f"{cfg}.cfg", folder / f"{cfg}.weights",
                      (folder / names).read_text().split("\n"), runtime=runtime)
    assert det.runtime == runtime
    rgb = cv2.cvtColor(cv2.imread(str(PERSON)), cv2.COLOR_BGR2RGB)
    people = [b for b in det.detect(rgb) if b.class_id == 0]
    assert people and people[0].score > 0.9
    p = people[0]
    # the person stands at about x 180-270, y 90-380 in the 640x424 photo
    assert 150 < (p.x0 + p.x1) / 2 < 300 and 200 < (p.y0 + p.y1) / 2 < 300 and p.y1 - p.y0 > 200


@pytest.mark.parametrize("runtime", ["opencv", "torch"])
def test_a_smaller_input_finds_the_same_person(runtime):
    rgb = cv2.cvtColor(cv2.imread(str(PERSON)), cv2.COLOR_BGR2RGB)
    small = YoloFastest(*COCO_FILES, ["x"] * 80, runtime=runtime, input_size=(256, 192))
    assert [h.shape[-2:] for h in small.raw(rgb)] == [(6, 8), (12, 16)]
    p = next(b for b in small.detect(rgb) if b.class_id == 0)
    # as at the cfg's 320 x 320: the person stands at about x 180-270, y 90-380 in the 640x424 photo
    assert p.score > 0.9
    assert 150 < (p.x0 + p.x1) / 2 < 300 and 200 < (p.y0 + p.y1) / 2 < 300 and p.y1 - p.y0 > 200


def test_an_input_size_that_is_not_a_multiple_of_32_is_refused():
    with pytest.raises(ValueError, match="multiples of 32"):
        YoloFastest(*COCO_FILES, ["x"] * 80, input_size=(320, 240))


def test_opencv_runtime_matches_pytorch():
    rgb = cv2.cvtColor(cv2.imread(str(PERSON)), cv2.COLOR_BGR2RGB)
    dnn = YoloFastest(*COCO_FILES, ["x"] * 80, runtime="opencv")
    assert dnn.runtime == "opencv"
    ours = dnn.raw(rgb)
    ref = YoloFastest(*COCO_FILES, ["x"] * 80, runtime="torch").raw(rgb)
    assert [o.shape for o in ours] == [r.shape for r in ref] == [(1, 255, 10, 10), (1, 255, 20, 20)]
    for o, r in zip(ours, ref):
        assert np.abs(o - r).max() < 1e-3


def test_onnx_export_is_built_once_then_read_from_the_cache(empty_onnx_cache, monkeypatch):
    builds = []
    build = onnx_export.export_onnx
    monkeypatch.setattr(onnx_export, "export_onnx", lambda net, path: (builds.append(path), build(net, path)))
    assert YoloFastest(*COCO_FILES, ["x"] * 80).runtime == "opencv"
    files = list(empty_onnx_cache.iterdir())
    assert builds == files == [onnx_export.cache_path(*COCO_FILES)]
    built = files[0].stat().st_mtime_ns
    assert YoloFastest(*COCO_FILES, ["x"] * 80).runtime == "opencv"
    assert len(builds) == 1 and files[0].stat().st_mtime_ns == built
    body = (BODY / "yolo-fastest-1.1_body.cfg", BODY / "yolo-fastest-1.1_body.weights")
    assert onnx_export.cache_path(*body) != files[0]


def test_a_cached_export_runs_without_importing_pytorch(empty_onnx_cache):
    YoloFastest(*COCO_FILES, ["x"] * 80)  # builds the export into the cache
    script = (
        "import sys, cv2\n"
        "import osslam.frontend.gate_process\n"
        "from osslam.frontend.detection.yolo import YoloFastest\n"
        f"det = YoloFastest({str(COCO_FILES[0])!r}, {str(COCO_FILES[1])!r}, ['x'] * 80)\n"
        f"boxes = det.detect(cv2.cvtColor(cv2.imread({str(PERSON)!r}), cv2.COLOR_BGR2RGB))\n"
        "print(det.runtime, boxes[0].label, 'torch' in sys.modules)\n")
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["opencv", "x", "False"]


def test_a_corrupt_cached_export_is_rebuilt(empty_onnx_cache, caplog):
    path = onnx_export.cache_path(*COCO_FILES)
    path.parent.mkdir(parents=True)
    path.write_bytes(b"\x08\x07half a file")
    with caplog.at_level("WARNING"):
        det = YoloFastest(*COCO_FILES, ["x"] * 80)
    assert det.runtime == "opencv" and path.stat().st_size > 100_000
    assert f"{path}: not a readable ONNX network" in caplog.text and "rebuilding" in caplog.text
    assert det.detect(cv2.cvtColor(cv2.imread(str(PERSON)), cv2.COLOR_BGR2RGB))[0].class_id == 0


def test_without_the_onnx_package_detection_falls_back_to_pytorch(empty_onnx_cache, monkeypatch, caplog):
    monkeypatch.setitem(sys.modules, "onnx", None)  # `import onnx` fails
    with caplog.at_level("WARNING"):
        det = YoloFastest(*COCO_FILES, ["x"] * 80)
    assert det.runtime == "torch" and det.dnn is None
    assert "ONNX export failed" in caplog.text and "runs in PyTorch" in caplog.text
    assert not empty_onnx_cache.exists() or not list(empty_onnx_cache.iterdir())  # no half-written file left


def test_unknown_runtime_and_classes_and_detection_intervals_below_one_are_refused():
    from osslam.config import DetectionConfig
    from osslam.frontend.detection.detector import make_detector

    with pytest.raises(ValueError, match=r"runtime 'tensorrt' unknown \(opencv, torch\)"):
        YoloFastest(*COCO_FILES, ["x"] * 80, runtime="tensorrt")
    with pytest.raises(ValueError, match=r"detection\.runtime 'onnx' unknown \(opencv, torch\)"):
        make_detector(DetectionConfig(runtime="onnx"), MODELS)
    with pytest.raises(ValueError, match=r"detection\.interval must be 1 or more, not 0"):
        make_detector(DetectionConfig(interval=0), MODELS)
    with pytest.raises(ValueError, match=r"detection\.person_interval must be 1 or more, not -1"):
        make_detector(DetectionConfig(person_interval=-1), MODELS)
    with pytest.raises(ValueError, match=r"detection\.classes: 'persons' not among yolo-fastest-1\.1's classes"):
        make_detector(DetectionConfig(classes=["chair", "persons"]), MODELS)  # a typo would detect nothing
    with pytest.raises(ValueError, match=r"'chair' not among yolo-fastest-1\.1-body's classes \(person\)"):
        make_detector(DetectionConfig(model="yolo-fastest-1.1-body", classes=["person", "chair"]), MODELS)


def test_bad_darknet_files_name_file_and_line(tmp_path):
    cfg = tmp_path / "bad.cfg"
    cfg.write_text("[net]\nwidth=320\n[lstm]\nsize=3\n")
    with pytest.raises(InputError, match=r"bad\.cfg:3.*lstm"):
        parse_cfg(cfg)
    short = tmp_path / "short.weights"
    short.write_bytes((COCO / "yolo-fastest-1.1.weights").read_bytes()[:100_000])
    with pytest.raises(InputError, match="short.weights"):
        YoloFastest(COCO / "yolo-fastest-1.1.cfg", short, ["x"] * 80)


def test_box_mask_keeps_the_dominant_depth_layer():
    from osslam.frontend.detection.masks import box_mask
    from osslam.frontend.detection.yolo import Box

    depth = np.full((100, 100), 3.0, np.float32)  # wall
    depth[20:80, 30:60] = 1.5  # the person, filling most of the box
    depth[20:30, 30:60] = 0.0  # no depth at the top of the head
    m = box_mask(Box(25, 15, 65, 85, 0, "person", 0.9), depth, 0.4)
    assert m[20:80, 30:60].all()
    assert not m[50, 62] and not m[50, 27]  # wall pixels inside the box are left out
    assert not m[:15].any() and not m[:, 66:].any()


def test_gate_uses_the_detector_and_says_when_models_are_missing(tmp_path, caplog):
    from osslam.config import Config
    from osslam.datasets.synthetic import SyntheticConfig, SyntheticSequence
    from osslam.frontend.gating import DynamicGate

    seq = SyntheticSequence(SyntheticConfig(n_frames=1))
    cfg = Config()
    cfg.models.dir = str(MODELS)
    gate = DynamicGate(cfg, seq.intrinsics)
    assert gate.detector is not None
    photo = cv2.cvtColor(cv2.resize(cv2.imread(str(PERSON)), (640, 480)), cv2.COLOR_BGR2RGB)
    depth = np.full((480, 640), 2.0, np.float32)
    result = gate.process(photo, cv2.cvtColor(photo, cv2.COLOR_RGB2GRAY), depth)
    assert result.mask[300, 250]  # the person's body (photo scaled to 640x480)
    assert result.mask.mean() < 0.3 and "detection" in result.timings_ms
    cfg.models.dir = str(tmp_path / "empty")
    with caplog.at_level("WARNING"):
        assert DynamicGate(cfg, seq.intrinsics).detector is None
    assert "flow and geometry only" in caplog.text


def test_detection_only_gate_skips_flow():
    from osslam.config import Config
    from osslam.datasets.synthetic import SyntheticConfig, SyntheticSequence
    from osslam.frontend.gating import DynamicGate

    seq = SyntheticSequence(SyntheticConfig(n_frames=2))
    cfg = Config()
    cfg.models.dir = str(MODELS)
    cfg.motion.enabled = False
    gate = DynamicGate(cfg, seq.intrinsics)
    for f in (seq[0], seq[1]):
        result = gate.process(f.rgb, cv2.cvtColor(f.rgb, cv2.COLOR_RGB2GRAY), f.depth)
    assert gate.flow is None and result.segmentation is None
    assert "flow" not in result.timings_ms and "detection" in result.timings_ms


def test_person_masks_come_from_the_segmentation_model_inside_the_box(caplog):
    from osslam.config import DetectionConfig
    from osslam.frontend.detection.detector import make_detector

    rgb = cv2.cvtColor(cv2.imread(str(PERSON)), cv2.COLOR_BGR2RGB)
    depth = np.full(rgb.shape[:2], 2.0, np.float32)  # flat depth: the depth layer alone keeps the whole box
    segmented = make_detector(DetectionConfig(), MODELS)
    assert segmented.segmenter is not None
    person = next(d for d in segmented.detect(rgb, depth) if d.label == "person")
    layered = next(d for d in make_detector(DetectionConfig(person_segmentation=False), MODELS).detect(rgb, depth)
                   if d.label == "person")
    ys, xs = np.nonzero(layered.mask)
    box_area = (xs.max() - xs.min() + 1) * (ys.max() - ys.min() + 1)
    assert layered.mask.sum() == box_area  # the box, filled
    assert 0.3 * box_area < person.mask.sum() < 0.8 * box_area  # the person's outline within it
    assert not (person.mask & ~layered.mask).any()
    assert person.mask[250, 225]  # the torso (the person stands at about x 180-270, y 90-380)


def test_a_person_mask_filling_little_of_its_box_falls_back_to_the_depth_layer():
    from osslam.config import DetectionConfig
    from osslam.frontend.detection.detector import MIN_PERSON_FILL, make_detector
    from osslam.frontend.detection.masks import box_mask

    rgb = cv2.cvtColor(cv2.imread(str(PERSON)), cv2.COLOR_BGR2RGB)
    depth = np.full(rgb.shape[:2], 2.0, np.float32)
    detector = make_detector(DetectionConfig(), MODELS)
    box = next(b for b in detector.yolo.detect(rgb, 0.5) if b.label == "person")

    class Partial:
        """A segmenter that finds only the top ``fill`` of the box (a torso cut off by the image edge)."""

        def __init__(self, fill):
            self.fill = fill

        def mask_in_box(self, rgb, corners):
            x0, y0, x1, y1 = corners
            self.mask = np.zeros(rgb.shape[:2], bool)
            self.mask[y0:y0 + int(self.fill * (y1 - y0)), x0:x1] = True
            return self.mask

    detector.segmenter = Partial(MIN_PERSON_FILL - 0.05)
    person = next(d for d in detector.detect(rgb, depth) if d.label == "person")
    assert np.array_equal(person.mask, box_mask(box, depth, detector.cfg.depth_layer))
    detector.segmenter = Partial(MIN_PERSON_FILL + 0.05)
    person = next(d for d in detector.detect(rgb, depth) if d.label == "person")
    assert np.array_equal(person.mask, detector.segmenter.mask)


def test_a_carried_person_mask_that_fills_the_box_stands_in_for_segmentation():
    from osslam.config import DetectionConfig
    from osslam.frontend.detection.detector import MIN_PERSON_FILL, make_detector

    rgb = cv2.cvtColor(cv2.imread(str(PERSON)), cv2.COLOR_BGR2RGB)
    depth = np.full(rgb.shape[:2], 2.0, np.float32)
    detector = make_detector(DetectionConfig(), MODELS)
    box = next(b for b in detector.yolo.detect(rgb, 0.5) if b.label == "person")
    x0, y0, x1, y1 = max(0, int(box.x0)), max(0, int(box.y0)), int(np.ceil(box.x1)), int(np.ceil(box.y1))
    segmented = next(d for d in detector.detect(rgb, depth) if d.label == "person").mask

    def band(fill):
        """The top ``fill`` of the box."""
        people = np.zeros(rgb.shape[:2], bool)
        people[y0:y0 + int(fill * (y1 - y0)), x0:x1] = True
        return people

    assert x1 < rgb.shape[1] - 5  # room right of the box for a stray patch
    known = band(MIN_PERSON_FILL + 0.05)
    stray = np.zeros_like(known)
    stray[y0:y1, -5:] = True  # a carried person outside this box
    person = next(d for d in detector.detect(rgb, depth, known | stray) if d.label == "person")
    assert np.array_equal(person.mask, known)  # the carried mask inside the box, nothing outside it
    too_little = next(d for d in detector.detect(rgb, depth, band(MIN_PERSON_FILL - 0.05)) if d.label == "person")
    assert np.array_equal(too_little.mask, segmented)  # segmented afresh
