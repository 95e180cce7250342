"""Scene configurations: frozen dataclasses with named presets per scene kind."""

from __future__ import annotations

import dataclasses
import hashlib
import json
from dataclasses import dataclass, field

SCENES = ("comet", "uav")
PRESETS = ("small", "default", "large")


@dataclass(frozen=True)
class CometParams:
    """Procedural comet and its photographic orbit (lengths in metres, angles in degrees)."""

    length_m: float = 4000.0  # long-axis extent of the procedural body (67P: ~4.1 km)
    relief: float = 0.06  # amplitude of low-frequency radial relief, fraction of the local radius
    fine_relief: float = 0.006  # amplitude of mid-frequency bumps (shading texture), same units
    step_deg: float = 8.0  # azimuth step between consecutive views (SfM wants <= ~15-20)
    latitude_mean_deg: float = 10.0  # mean sub-camera latitude
    latitude_amp_deg: float = 20.0  # latitude swing along the orbit (sinusoid)
    latitude_period_views: float = 20.0  # views per latitude cycle
    range_var: float = 0.15  # relative range swing along the orbit (sinusoid)
    fill: float = 0.8  # body bounding radius / half image width at mean range
    aim_jitter: float = 0.04  # look-at target jitter, fraction of the bounding radius (1 sigma)
    roll_jitter_deg: float = 8.0  # camera roll about the optical axis (1 sigma)
    sun_azimuth_deg: float = 60.0  # sun direction (world frame, fixed: a short imaging arc)
    sun_elevation_deg: float = 25.0
    sun_irradiance: float = 3.0  # radiance scale of the sun (albedo ~0.06-0.55)
    fill_irradiance: float = 0.6  # weak second light from the opposite side, keeps shadows textured


@dataclass(frozen=True)
class UavParams:
    """Height-field terrain with box buildings and a lawnmower flight (metres, degrees)."""

    altitude_m: float = 80.0  # flying height above the mean terrain level
    forward_overlap: float = 0.8  # along-track overlap of consecutive images
    side_overlap: float = 0.6  # across-track overlap of adjacent lines
    oblique_deg: float = 0.0  # forward tilt of the camera from nadir (0 = nadir)
    terrain_relief_m: float = 6.0  # amplitude of low-frequency terrain height
    buildings: int = 12  # number of box buildings in the block
    building_height_m: tuple[float, float] = (6.0, 20.0)  # min/max building height
    sun_azimuth_deg: float = 135.0
    sun_elevation_deg: float = 50.0
    sun_irradiance: float = 2.5
    fill_irradiance: float = 0.6


@dataclass(frozen=True)
class SceneConfig:
    """Everything that decides a rendered scene; the hash of this decides cache folders."""

    scene: str = "comet"  # "comet" or "uav"
    preset: str = "default"  # name of the preset these values came from (recorded only)
    views: int = 28  # number of images
    width: int = 640  # image width, pixels
    height: int = 480  # image height, pixels
    fov_deg: float = 30.0  # horizontal field of view (OSIRIS NAC: 2.2; WAC: 12)
    spp: int = 16  # samples per pixel
    seed: int = 0  # seeds the shape, texture, orbit jitter and the renderer
    mesh: str | None = None  # comet only: OBJ/PLY shape model (metres) instead of the procedural body
    texture_cell_px: float = 4.0  # finest albedo cell, in image pixels at the mean viewing range
    comet: CometParams = field(default_factory=CometParams)
    uav: UavParams = field(default_factory=UavParams)

    def validate(self) -> None:
        """Raise ValueError naming the first bad field."""
        if self.scene not in SCENES:
            raise ValueError(f"unknown scene {self.scene!r} (choose from {', '.join(SCENES)})")
        for name in ("views", "width", "height", "spp"):
            if getattr(self, name) <= 0:
                raise ValueError(f"{name} must be positive, got {getattr(self, name)}")
        if self.views < 2:
            raise ValueError(f"views must be >= 2, got {self.views}")
        if not 0.0 < self.fov_deg < 170.0:
            raise ValueError(f"fov_deg must be in (0, 170), got {self.fov_deg}")
        if self.texture_cell_px <= 0:
            raise ValueError(f"texture_cell_px must be positive, got {self.texture_cell_px}")
        if self.mesh is not None and self.scene != "comet":
            raise ValueError("mesh is only supported for the comet scene")
        if self.scene == "uav" and not (0 <= self.uav.forward_overlap < 1 and 0 <= self.uav.side_overlap < 1):
            raise ValueError("uav overlaps must lie in [0, 1)")

    def relevant(self) -> dict:
        """The fields that affect the output (the other scene's params are dropped)."""
        d = dataclasses.asdict(self)
        d.pop("uav" if self.scene == "comet" else "comet")
        d.pop("preset")
        return d

    def digest(self, code_version: str) -> str:
        """Short hash of the relevant params and the synth code version."""
        blob = json.dumps({"params": self.relevant(), "code": code_version}, sort_keys=True)
        return hashlib.sha256(blob.encode()).hexdigest()[:10]


_PRESETS: dict[tuple[str, str], dict] = {
    # Small: wider FOV, longer arc and a fuller frame than default, so 12 views at 320x240 give
    # pycolmap enough features and enough perspective (measured: mean rotation error 0.08-0.17 deg).
    ("comet", "small"): dict(views=12, width=320, height=240, spp=8, fov_deg=45.0,
                             comet=CometParams(step_deg=10.0, fill=1.0)),
    ("comet", "default"): dict(views=28, width=640, height=480, spp=16),
    ("comet", "large"): dict(views=300, width=640, height=480, spp=16,
                             comet=CometParams(step_deg=4.0, latitude_amp_deg=35.0,
                                               latitude_period_views=90.0)),
    ("uav", "small"): dict(views=12, width=320, height=240, spp=8, fov_deg=60.0, uav=UavParams(buildings=4)),
    ("uav", "default"): dict(views=28, width=640, height=480, spp=16, fov_deg=60.0),
    ("uav", "large"): dict(views=300, width=640, height=480, spp=16, fov_deg=60.0,
                           uav=UavParams(buildings=80)),
}


def preset(scene: str, name: str = "default", **overrides) -> SceneConfig:
    """Named preset for ``scene``, with field overrides (unknown keys raise TypeError)."""
    if scene not in SCENES:
        raise ValueError(f"unknown scene {scene!r} (choose from {', '.join(SCENES)})")
    if name not in PRESETS:
        raise ValueError(f"unknown preset {name!r} (choose from {', '.join(PRESETS)})")
    return SceneConfig(scene=scene, preset=name, **{**_PRESETS[(scene, name)], **overrides})
