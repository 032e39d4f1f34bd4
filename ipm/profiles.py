"""Named budgets for the differentiable path: ``smoke`` (CI), ``default``, ``paper`` (authors' settings)."""
from __future__ import annotations

from dataclasses import dataclass, replace

from ipm.errors import UserError
from ipm.render.cameras import is_fov_deg


WINDOW_LOSSES = ("mse", "dice")
"""Losses of the class-mask term (``ipm.render.silhouette._pyramid_loss``)."""

RENDERERS = ("auto", "jax", "mitsuba")
"""Silhouette renderers of the diff path (``DiffProfile.renderer``)."""


@dataclass(frozen=True)
class DiffProfile:
    """Settings of the memetic stage and the coarse-to-fine Adam refinement."""

    population: int = 16
    """Individuals in the memetic population (initialised from presets and random samples)."""
    ga_iterations: int = 20
    """Generations of the memetic algorithm."""
    adam_per_iteration: int = 160
    """Adam steps per generation, shared among individuals by quality."""
    remove_share: float = 0.2
    """Share of the worst individuals removed each generation."""
    mutate_share: float = 0.5
    """Share of the population replaced by mutants of good individuals each generation."""
    random_share: float = 0.25
    """Share of the initial population drawn at random instead of from presets."""
    yaw_bins: int = 16
    """Initialisation bins of the yaw angle; individuals in the same bin are merged (one bin for an object that
    looks the same turned: docs/decisions.md, 'One yaw bin for turned look-alikes')."""
    lr: float = 0.05
    """Adam learning rate (unit-cube parameters; radians; object sizes)."""
    reject_ratio: float = 1.2
    """A step that raises the loss by more than this factor is undone and the rate halved."""
    reg_weight: float = 0.33
    """Weight of the parameter regulariser (smoothness of the handle's control sequences)."""
    memetic_res: int = 128
    """Render width of the memetic stage (pixels)."""
    memetic_lod: int = 0
    """Generator level of detail in the memetic stage."""
    refine_res: tuple[int, ...] = (256, 512)
    """Render widths of the refinement stages (doubling)."""
    refine_iterations: tuple[int, ...] = (250, 250)
    """Adam steps per refinement stage (docs/decisions.md, 'Last stage length')."""
    refine_lod: int = 1
    """Generator level of detail during refinement and for the output mesh."""
    output_lod: int = 1
    """Generator level of detail of the written mesh (level 2's 128-gon pole fans have 2.8-degree angles,
    which the malformed-triangle metric would count; docs/decisions.md, 'Output level of detail')."""
    refine_candidates: int = 1
    """Finalists of the memetic stage (distinct topologies or yaws, ``ipm.methods.diff.finalists``) each polished
    and taken through the first refinement stage; the lowest loss goes on (docs/decisions.md, 'Finalists')."""
    polish_sweeps: int = 2
    """Sweeps of the discrete hill climb after the memetic stage (``ipm.methods.diff.polish``), which leaves the
    counts ``read_counts`` settles alone; 0: none (docs/decisions.md, 'Polish')."""
    polish_steps: int = 6
    """Adam steps given to each neighbour before it is compared."""
    decide_steps: int = 0
    """Adam steps each value of a categorical parameter (``Generator.categorical``: the roof type), and each
    turned, gets before the last refinement stage (``ipm.methods.diff.decide``); 0: none
    (docs/decisions.md, 'Roof race')."""
    decide_rounds: int = 1
    """Rounds of decide's race: after each, the better half of the candidates (at least two) get ``decide_steps``
    more Adam steps; 1: the lowest loss after one round wins (docs/decisions.md, 'Roof race')."""
    decide_turns: bool = True
    """Whether decide also tries each value turned a quarter (width and depth traded, the counts read in again)
    for a generator with a front (``Generator.marker``) (docs/decisions.md, 'Roof race')."""
    decide_least: bool = False
    """Whether a value decide tries starts the continuous parameters it turns on at their lower bounds, the new
    kind nearest the old; off (docs/decisions.md, 'Tried and dropped')."""
    decide_shares: tuple[float, ...] = ()
    """Shares of the object's height decide also tries giving to a pitched roof, for each value and each turn
    (``Generator.split_roof``: the walls take the rest); (): none (docs/decisions.md, 'Height shares')."""
    sight_steps: int = 0
    """Adam steps of each start of the line-of-sight sweep (``ipm.methods.diff.sweep_sight``: the footprint
    side the first view looks along tried at each of ``sight_factors``, near face held); 0: none
    (docs/decisions.md, 'Line-of-sight sweep')."""
    sight_factors: tuple[float, ...] = (0.7, 0.84, 1.19, 1.43)
    """The stretches ``sight_steps`` tries (about 18 % apart in the log)."""
    sight_margin: float = 0.05
    """A stretch replaces the extent as it stands only with a loss lower by more than this fraction
    (docs/decisions.md, 'Line-of-sight sweep')."""
    place_steps: int = 0
    """Adam steps of each start of the chimney sweep (``ipm.methods.diff.sweep_place``: the fit as it stands
    and its small part at each of ``Generator.placements``), after ``sight_steps``; 0: none
    (docs/decisions.md, 'Chimney sweep')."""
    place_margin: float = 0.4
    """A placement replaces the part as it stands only with a loss lower by more than this fraction
    (docs/decisions.md, 'Chimney sweep')."""
    recentre: bool = True
    """Before each refinement stage, trade the lengths against the pose scale (the same mesh,
    :meth:`ipm.problem.Problem.recentred`) so they sit midway between their bounds
    (docs/decisions.md, 'Re-centring')."""
    focal_sweep: int = 0
    """For an unknown field of view (``ipm.photo``): before the last stage the focal gene is held at the
    estimate's and at this many points either side, the lowest loss wins (``ipm.methods.diff.sweep_focal``);
    0: none (docs/decisions.md, 'Focal sweep')."""
    pitch_bins: int = 1
    """For an unknown camera: the memetic stage keeps the best individual per topology, yaw bin and one of
    this many pitch bins over ``PITCH_PRIOR`` (``ipm.methods.diff.pitch_niche``); 1: none
    (docs/decisions.md, 'Pitch bins')."""
    pitch_starts: tuple[float, ...] = ()
    """For an unknown camera with a given field of view: the memetic stage is run again per pitch here (degrees),
    held there, the finalists drawn from all runs; (): the usual stage alone (docs/decisions.md, 'Pitch starts')."""
    focal_step: float = 0.1
    """Grid step of ``focal_sweep`` in log focal length (0.1: about 10 % in focal length)."""
    focal_steps: int = 100
    """Adam steps each point of ``focal_sweep`` gets, starting from its inner neighbour's result."""
    pitch_sweep: int = 0
    """With ``focal_sweep``, after it: the camera's pitch held at the estimate's and this many points either side,
    ``pitch_step`` degrees apart, walked the same way; 0: none (docs/decisions.md, 'Pitch walk')."""
    pitch_step: float = 0.25
    """Grid step of ``pitch_sweep`` in degrees."""
    fov_grid: tuple[float, ...] = ()
    """For an unknown field of view: a fit per value here (horizontal degrees) as if it were given, the lowest loss
    kept (``ipm.methods.diff.fit_fov_grid``); (): estimated in one fit (docs/decisions.md, 'Field-of-view grid')."""
    read_counts: bool = True
    """Before each refinement stage, set the counts (storeys, windows per facade) to those the
    input views' class masks show on the facades they face (``ipm.facades``); needs class masks
    (buildings' window masks) and a ``window_weight`` above 0, else nothing happens."""
    occam_tolerance: float = 0.03
    """A discrete parameter goes to its simplest value (no handle) if that raises the final loss
    by at most this share: one view cannot tell a handle hidden behind the body from none."""
    spp: int = 4
    """Samples per pixel of the silhouette renders."""
    renderer: str = "auto"
    """Silhouette renderer: ``jax`` (``ipm.render.edges``), ``mitsuba`` (``ipm.render.silhouette``) or ``auto``:
    jax, but Mitsuba for an unknown camera whose field of view is estimated (docs/decisions.md, 'Renderer auto')."""
    memetic_batch: bool = False
    """Evaluate the memetic population's steps a round at a time, one batched JAX call per topology
    (``ipm.optim.memetic.adam_steps_together``; silhouettes only); off (docs/decisions.md, 'Memetic batching')."""
    window_weight: float = 1.0
    """Weight of the class-mask term beside the silhouette (the generator's ``mask_class``:
    buildings' windows; used when the views have semantic images); 0 = the silhouette alone
    (docs/decisions.md, 'Window term')."""
    extra_class_weight: float = 0.0
    """Weight of the class-mask term of each of the generator's ``extra_mask_classes`` (buildings: roof; the
    windows' pyramid and loss); 0 = none (docs/decisions.md, 'Tried and dropped')."""
    window_levels: int = 4
    """Levels of the 2 x 2 mean pyramid over which the class-mask term is averaged (1: the
    full-resolution MSE alone)."""
    window_loss: str = "mse"
    """Loss of the class-mask term on each pyramid level: ``mse`` or ``dice``
    (``ipm.render.silhouette._pyramid_loss``; ``dice`` wants a weight of about 0.01;
    docs/decisions.md, 'Window term')."""
    max_tilt: float = 0.0
    """Bound of the two tilt angles (radians); 0 holds the object upright, the scene convention.
    Raise it for objects that may lean (docs/decisions.md, 'Upright objects')."""


PROFILES = {
    "paper": DiffProfile(),
    # default: sizes and stages chosen on dev (docs/decisions.md, 'Memetic stage size', 'Last stage length' and
    # the sections named in DiffProfile's fields)
    "default": DiffProfile(population=16, ga_iterations=12, adam_per_iteration=64, memetic_res=96,
                           refine_res=(128, 256), refine_iterations=(100, 300), refine_candidates=3,
                           decide_steps=30, decide_rounds=3, decide_shares=(0.3, 0.6), sight_steps=90,
                           place_steps=40, focal_sweep=3, pitch_sweep=2,
                           pitch_starts=(7.5, 22.5, 37.5, 52.5)),
    "smoke": DiffProfile(population=4, ga_iterations=2, adam_per_iteration=6, memetic_res=32,
                         refine_res=(48,), refine_iterations=(4,), output_lod=0, refine_lod=0, spp=2,
                         polish_sweeps=1, polish_steps=1, focal_sweep=1, focal_steps=1),
}


def get_profile(name: str, **overrides) -> DiffProfile:
    """The named profile with ``overrides`` applied; ``UserError`` for unknown names."""
    if name not in PROFILES:
        raise UserError(f"unknown profile {name!r} (known: {', '.join(PROFILES)})")
    unknown = sorted(set(overrides) - set(DiffProfile.__dataclass_fields__))
    if unknown:
        raise UserError(f"unknown diff setting(s) {', '.join(unknown)} (known: {', '.join(DiffProfile.__dataclass_fields__)})")
    prof = replace(PROFILES[name], **overrides)
    if prof.renderer not in RENDERERS:
        raise UserError(f"unknown renderer {prof.renderer!r} (known: {', '.join(RENDERERS)})")
    if prof.window_loss not in WINDOW_LOSSES:
        raise UserError(f"unknown window_loss {prof.window_loss!r} (known: {', '.join(WINDOW_LOSSES)})")
    if not all(is_fov_deg(f) for f in prof.fov_grid):
        raise UserError(f"fov_grid: needs fields of view of 1 to 170 degrees, got {list(prof.fov_grid)}")
    return replace(prof, fov_grid=tuple(float(f) for f in prof.fov_grid))
