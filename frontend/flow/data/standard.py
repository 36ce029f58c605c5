"""The standard flow benchmarks in their published folder layouts: FlyingChairs, FlyingThings3D, Sintel, KITTI-2015, HD1K."""

from __future__ import annotations

from dataclasses import dataclass
from itertools import pairwise
from pathlib import Path

from osslam.errors import InputError

from .formats import read_flow, read_image
from .sample import FlowSample


@dataclass(frozen=True)
class PairFiles:
    """The files of one training pair."""

    image1: Path
    image2: Path
    flow: Path


class FileFlowDataset:
    """Image pairs and flow files listed up front, read on access."""

    def __init__(self, name: str, root: Path, pairs: list[PairFiles]):
        if not pairs:
            raise InputError(root, f"no {name} image pairs with flow found (check the folder layout)")
        self.name = name
        self.pairs = pairs

    def __len__(self) -> int:
        return len(self.pairs)

    def __getitem__(self, i: int) -> FlowSample:
        p = self.pairs[i]
        flow, valid = read_flow(p.flow)
        return FlowSample(read_image(p.image1), read_image(p.image2), flow, valid)


def flying_chairs(root: str | Path, split: str = "train") -> FileFlowDataset:
    """FlyingChairs: ``data/NNNNN_img1.ppm``, ``_img2.ppm``, ``_flow.flo``; ``FlyingChairs_train_val.txt`` picks the split."""
    root = Path(root)
    flows = sorted((root / "data").glob("*_flow.flo"))
    split_file = root / "FlyingChairs_train_val.txt"
    if split_file.is_file():
        labels = split_file.read_text().split()
        if len(labels) != len(flows):
            raise InputError(split_file, f"{len(labels)} split labels for {len(flows)} flow files")
        wanted = "1" if split == "train" else "2"
        flows = [f for f, label in zip(flows, labels) if label == wanted]
    pairs = [PairFiles(f.with_name(f.name.replace("_flow.flo", "_img1.ppm")),
                       f.with_name(f.name.replace("_flow.flo", "_img2.ppm")), f) for f in flows]
    return FileFlowDataset("FlyingChairs", root, pairs)


def flying_things(root: str | Path, split: str = "TRAIN", passes: str = "frames_cleanpass") -> FileFlowDataset:
    """FlyingThings3D: ``PASS/SPLIT/X/NNNN/left/FFFF.png`` with ``optical_flow/SPLIT/X/NNNN/into_future/left/OpticalFlowIntoFuture_FFFF_L.pfm``."""
    root = Path(root)
    pairs = []
    for scene in sorted((root / passes / split).glob("*/*")):
        images = sorted((scene / "left").glob("*.png"))
        flow_dir = root / "optical_flow" / split / scene.parent.name / scene.name / "into_future" / "left"
        for a, b in pairwise(images):
            flow = flow_dir / f"OpticalFlowIntoFuture_{a.stem}_L.pfm"
            if flow.is_file():
                pairs.append(PairFiles(a, b, flow))
    return FileFlowDataset("FlyingThings3D", root, pairs)


def sintel(root: str | Path, dstype: str = "clean") -> FileFlowDataset:
    """MPI-Sintel: ``training/DSTYPE/SCENE/frame_NNNN.png`` with ``training/flow/SCENE/frame_NNNN.flo``."""
    root = Path(root)
    pairs = []
    for scene in sorted((root / "training" / dstype).iterdir() if (root / "training" / dstype).is_dir() else []):
        images = sorted(scene.glob("*.png"))
        for a, b in pairwise(images):
            pairs.append(PairFiles(a, b, root / "training" / "flow" / scene.name / f"{a.stem}.flo"))
    return FileFlowDataset("Sintel", root, pairs)


def kitti2015(root: str | Path) -> FileFlowDataset:
    """KITTI-2015: ``training/image_2/NNNNNN_10.png``, ``_11.png`` with ``training/flow_occ/NNNNNN_10.png``."""
    root = Path(root)
    flows = sorted((root / "training" / "flow_occ").glob("*_10.png"))
    image_dir = root / "training" / "image_2"
    pairs = [PairFiles(image_dir / f.name, image_dir / f.name.replace("_10.png", "_11.png"), f) for f in flows]
    return FileFlowDataset("KITTI-2015", root, pairs)


def hd1k(root: str | Path) -> FileFlowDataset:
    """HD1K: ``hd1k_input/image_2/SSSSSS_FFFF.png`` with ``hd1k_flow_gt/flow_occ/SSSSSS_FFFF.png`` (frame to the next)."""
    root = Path(root)
    pairs = []
    for flow in sorted((root / "hd1k_flow_gt" / "flow_occ").glob("*_*.png")):
        seq, frame = flow.stem.split("_")
        nxt = root / "hd1k_input" / "image_2" / f"{seq}_{int(frame) + 1:0{len(frame)}d}.png"
        if nxt.is_file():
            pairs.append(PairFiles(root / "hd1k_input" / "image_2" / flow.name, nxt, flow))
    return FileFlowDataset("HD1K", root, pairs)


#: Dataset builders by the name a training config uses.
LAYOUTS = {"chairs": flying_chairs, "things": flying_things, "sintel": sintel, "kitti": kitti2015, "hd1k": hd1k}
