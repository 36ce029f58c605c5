"""The TUM RGB-D benchmark's sequences: names, freiburg camera ids, upstream archives and sizes.

Sizes are the approximate ``.tgz`` sizes in MB, for information and progress only; TUM
publishes no checksums, so a download's integrity comes from reading the whole archive.
"""

from __future__ import annotations

from dataclasses import dataclass

from osslam.errors import OsslamError

TUM_BASE_URL = "https://cvg.cit.tum.de/rgbd/dataset"


class CatalogueError(OsslamError):
    """A sequence name that is not in the TUM catalogue."""


@dataclass(frozen=True)
class TumEntry:
    """One TUM RGB-D sequence: ``freiburg`` camera id (1, 2, 3), short name, category, approximate size."""

    freiburg: int
    name: str
    category: str
    size_mb: int

    @property
    def folder(self) -> str:
        """The folder the archive extracts to, e.g. ``rgbd_dataset_freiburg1_xyz``."""
        return f"rgbd_dataset_freiburg{self.freiburg}_{self.name}"

    @property
    def short(self) -> str:
        """The short name, e.g. ``fr1/xyz``."""
        return f"fr{self.freiburg}/{self.name}"

    def url(self, base_url: str = TUM_BASE_URL) -> str:
        """The archive's address under ``base_url`` (upstream by default, or a mirror)."""
        return f"{base_url.rstrip('/')}/freiburg{self.freiburg}/{self.folder}.tgz"


_SEQUENCES: tuple[tuple[int, str, str, int], ...] = (
    # Testing and debugging
    (1, "xyz", "testing", 470), (1, "rpy", "testing", 420), (2, "xyz", "testing", 2390), (2, "rpy", "testing", 2150),
    # Handheld SLAM
    (1, "360", "handheld", 420), (1, "floor", "handheld", 1210), (1, "desk", "handheld", 360),
    (1, "desk2", "handheld", 370), (1, "room", "handheld", 830), (2, "360_hemisphere", "handheld", 1920),
    (2, "360_kidnap", "handheld", 910), (2, "desk", "handheld", 2010), (2, "large_no_loop", "handheld", 1800),
    (2, "large_with_loop", "handheld", 2310), (3, "long_office_household", "handheld", 1580),
    # Robot SLAM
    (2, "pioneer_360", "robot", 670), (2, "pioneer_slam", "robot", 1240), (2, "pioneer_slam2", "robot", 900),
    (2, "pioneer_slam3", "robot", 1150),
    # Structure vs. texture
    (3, "nostructure_notexture_far", "structure_texture", 800),
    (3, "nostructure_notexture_near_withloop", "structure_texture", 1060),
    (3, "nostructure_texture_far", "structure_texture", 780),
    (3, "nostructure_texture_near_withloop", "structure_texture", 1300),
    (3, "structure_notexture_far", "structure_texture", 780), (3, "structure_notexture_near", "structure_texture", 700),
    (3, "structure_texture_far", "structure_texture", 900), (3, "structure_texture_near", "structure_texture", 1000),
    # Dynamic objects
    (2, "desk_with_person", "dynamic", 2700), (3, "sitting_static", "dynamic", 350), (3, "sitting_xyz", "dynamic", 730),
    (3, "sitting_halfsphere", "dynamic", 580), (3, "sitting_rpy", "dynamic", 450),
    (3, "walking_static", "dynamic", 560), (3, "walking_xyz", "dynamic", 550),
    (3, "walking_halfsphere", "dynamic", 620), (3, "walking_rpy", "dynamic", 580),
    # 3D object reconstruction
    (1, "plant", "objects", 730), (1, "teddy", "objects", 840), (2, "coke", "objects", 1500),
    (2, "dishes", "objects", 1560), (2, "flowerbouquet", "objects", 1440),
    (2, "flowerbouquet_brownbackground", "objects", 1700), (2, "metallic_sphere", "objects", 1300),
    (2, "metallic_sphere2", "objects", 1900), (3, "cabinet", "objects", 600), (3, "large_cabinet", "objects", 500),
    (3, "teddy", "objects", 1300),
)

#: Every catalogued sequence, by short name (``fr1/xyz``).
TUM_SEQUENCES: dict[str, TumEntry] = {e.short: e for e in (TumEntry(*row) for row in _SEQUENCES)}


def tum_entry(name: str) -> TumEntry:
    """The catalogue entry for ``fr1/xyz``, ``freiburg1_xyz`` or ``rgbd_dataset_freiburg1_xyz``."""
    key = name.strip().strip("/")
    key = key.removeprefix("rgbd_dataset_").removesuffix(".tgz")
    if key.startswith("freiburg") and "_" in key:
        fr, _, rest = key.partition("_")
        key = f"fr{fr.removeprefix('freiburg')}/{rest}"
    entry = TUM_SEQUENCES.get(key)
    if entry is None:
        raise CatalogueError(f"unknown TUM sequence '{name}' (see `osslam download tum --list`)")
    return entry
