"""Scene configurations: frozen dataclasses with named presets per scene kind."""

from __future__ import annotations

import dataclasses
import hashlib
import json
from dataclasses import dataclass, field

SCENES = ("comet", "uav")
PRESETS = ("small", "default", "large")
# Twins of the paper's three datasets (Tables 1-3): twin name -> scene kind.
TWINS = {"rosetta": "comet", "poets-park": "uav", "mappilot": "uav"}
ROSETTA_MESH = ("comet67p", "67P_geodesynets_raw_9149v_m.obj")  # inside the reference data folder


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
    # "arc": one pass of azimuth steps; "raster": a mapping phase, back-and-forth azimuth passes
    # over the lit side (centre sun_azimuth + arc_offset_deg, half-width arc_half_deg), each pass at
    # the next latitude from latitude_mean - amp to latitude_mean + amp, the range swinging slowly.
    orbit: str = "arc"
    arc_half_deg: float = 60.0
    arc_offset_deg: float = 10.0
    range_period_views: float = 100.0  # raster only: views per range cycle


@dataclass(frozen=True)
class PriorParams:
    """Noisy pose priors written beside the exact GT (GPS/INS-like or orbit-determination-like).

    Errors are AR(1) along the image sequence (correlation ``correlation`` between consecutive
    views), so they drift like a navigation solution instead of jumping from image to image.
    """

    position_sigma_m: float = 0.0  # horizontal (UAV) or every axis (comet), 1 sigma; 0 = no priors
    position_sigma_rel: float = 0.0  # comet: added sigma as a fraction of the camera range
    vertical_sigma_m: float = 0.0  # UAV: vertical sigma (GPS height is worse); 0 = same as horizontal
    rotation_sigma_deg: float = 0.0  # attitude, 1 sigma per axis
    correlation: float = 0.9


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
    building_size_m: tuple[float, float] = (8.0, 22.0)  # min/max footprint side
    block_m: float = 0.0  # > 0: a street grid with this period; buildings only inside the blocks
    street_width_m: float = 12.0
    tree_cover: float = 0.0  # fraction of open ground under tree canopy (height-field bumps)
    tree_height_m: float = 8.0
    field_contrast: float = 0.0  # > 0: field patches (coarse albedo steps, mixed farmland)
    oblique_fraction: float = 0.0  # share of the views flown as oblique cross strips (along y)
    oblique_strip_deg: float = 0.0  # forward tilt of the cross-strip camera
    max_grid_vertices: int = 1_500_000  # above this the terrain grid coarsens (texture blurs)


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
    priors: PriorParams = field(default_factory=PriorParams)

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
        if self.scene == "uav" and not 0 <= self.uav.oblique_fraction < 1:
            raise ValueError("uav oblique_fraction must lie in [0, 1)")
        if self.comet.orbit not in ("arc", "raster"):
            raise ValueError(f"comet orbit must be 'arc' or 'raster', got {self.comet.orbit!r}")

    def relevant(self) -> dict:
        """The fields that affect the output (the other scene's params are dropped)."""
        d = dataclasses.asdict(self)
        d.pop("uav" if self.scene == "comet" else "comet")
        d.pop("preset")
        if self.mesh:  # the shape decides the pixels, not where the file lies on this machine
            from pathlib import Path

            path = Path(self.mesh)
            d["mesh"] = hashlib.sha256(path.read_bytes()).hexdigest() if path.is_file() else self.mesh
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


# Twins of the paper's datasets. Sizes and spp are chosen so that the three render in about an
# hour on 2 cores (~2.5-3 s per view at spp 8 on the loaded machine). spp 8: with the box filter
# and ~4 px texture cells the sampling noise stays far below the texture contrast (measured on
# full-size views: spp 8 vs spp 32 differ by 3.9 DN rms on the comet's lit pixels, texture std
# 45 DN; 2.0 DN on the UAV, std 50 DN). The comet twin's mesh path is filled in by preset()
# from the reference data folder.
_PRESETS.update({
    # Rosetta mapping phase: WAC-like 12 deg FOV (range ~19 km, the nucleus fills the frame), one
    # Sun (no fill light: shadows are black, as in OSIRIS images), 16 passes of 41 views 3 deg
    # apart, latitude -25..55 deg, range +-15%. Orbit determination: ~100 m + 0.3% of the range.
    ("comet", "rosetta"): dict(
        views=631, width=1024, height=1024, spp=8, fov_deg=12.0,
        comet=CometParams(orbit="raster", step_deg=3.0, arc_half_deg=60.0, arc_offset_deg=10.0,
                          latitude_mean_deg=15.0, latitude_amp_deg=40.0, range_var=0.15,
                          range_period_views=230.0, fill=1.5, aim_jitter=0.03, roll_jitter_deg=8.0,
                          fill_irradiance=0.0),
        priors=PriorParams(position_sigma_m=100.0, position_sigma_rel=0.003, rotation_sigma_deg=0.05,
                           correlation=0.98)),
    # Poets park flats: an urban block of flats on a street grid with trees, 80/70% overlap,
    # 30% of the views as oblique (30 deg) cross strips. GPS/INS: 2 m, 4 m vertical, 1 deg.
    ("uav", "poets-park"): dict(
        views=857, width=1024, height=768, spp=8, fov_deg=60.0,
        uav=UavParams(altitude_m=90.0, forward_overlap=0.8, side_overlap=0.7, terrain_relief_m=3.0,
                      buildings=160, building_height_m=(9.0, 30.0), building_size_m=(10.0, 28.0),
                      block_m=70.0, street_width_m=14.0, tree_cover=0.25, tree_height_m=9.0,
                      oblique_fraction=0.3, oblique_strip_deg=30.0, max_grid_vertices=3_000_000),
        priors=PriorParams(position_sigma_m=2.0, vertical_sigma_m=4.0, rotation_sigma_deg=1.0,
                           correlation=0.9)),
    # MapPilot: a nadir lawnmower over mixed terrain (fields, woods, a few buildings, more
    # relief), 75/65% overlap. GPS/INS as above.
    ("uav", "mappilot"): dict(
        views=493, width=1024, height=768, spp=8, fov_deg=60.0,
        uav=UavParams(altitude_m=100.0, forward_overlap=0.75, side_overlap=0.65, terrain_relief_m=12.0,
                      buildings=25, building_height_m=(5.0, 12.0), tree_cover=0.3, tree_height_m=12.0,
                      field_contrast=0.6, max_grid_vertices=3_000_000),
        priors=PriorParams(position_sigma_m=2.0, vertical_sigma_m=4.0, rotation_sigma_deg=1.0,
                           correlation=0.9)),
})


def preset(scene: str, name: str = "default", **overrides) -> SceneConfig:
    """Named preset for ``scene``, with field overrides (unknown keys raise TypeError).

    ``name`` may also be a twin of ``scene`` (``rosetta`` for comet; ``poets-park``, ``mappilot``
    for uav); the rosetta twin needs the 67P shape model in the reference data folder.
    """
    if scene not in SCENES:
        raise ValueError(f"unknown scene {scene!r} (choose from {', '.join(SCENES)})")
    if name not in PRESETS and TWINS.get(name) != scene:
        twins = [t for t, s in TWINS.items() if s == scene]
        raise ValueError(f"unknown preset {name!r} for {scene} (choose from {', '.join((*PRESETS, *twins))})")
    values = {**_PRESETS[(scene, name)], **overrides}
    if name == "rosetta" and "mesh" not in values:
        from polarref.core.data import data_path

        values["mesh"] = str(data_path(*ROSETTA_MESH))
    return SceneConfig(scene=scene, preset=name, **values)


def twin(name: str, **overrides) -> SceneConfig:
    """The twin preset ``name`` (one of TWINS), with field overrides."""
    if name not in TWINS:
        raise ValueError(f"unknown twin {name!r} (choose from {', '.join(TWINS)})")
    return preset(TWINS[name], name, **overrides)
