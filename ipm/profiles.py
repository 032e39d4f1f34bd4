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
    """Initialisation bins of the yaw angle; individuals in the same bin are merged."""
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
    """Adam steps per refinement stage."""
    refine_lod: int = 1
    """Generator level of detail during refinement and for the output mesh."""
    output_lod: int = 1
    """Generator level of detail of the written mesh (level 2's 128-gon pole fans have 2.8 degree
    angles, which the malformed-triangle metric would count)."""
    refine_candidates: int = 1
    """Finalists of the memetic stage (distinct topologies or yaws, best first:
    ``ipm.methods.diff.finalists``) polished and taken through the first refinement stage each;
    the one with the lowest loss there goes on. 3 in the default profile: dev buildings (one view,
    seeds 0 and 1) 0.928 -> 0.936 mean IoU, worst 0.716 -> 0.784; dev cups (seed 0) unchanged
    within 0.005."""
    polish_sweeps: int = 2
    """Sweeps of the discrete hill climbing after the memetic stage (``ipm.methods.diff.polish``:
    each many-valued discrete parameter one value up and down, a categorical one to every other
    value, and the half turn; with ``read_counts`` not the counts read off the class masks just
    before, nor those of sides no view faces: no loss tells their values apart, and the next
    reading overwrites them; dev buildings, one view, seeds 0 and 1, 16 runs: mean IoU 0.957 ->
    0.959, worst 0.784 -> 0.800, building_1's polish 50 s -> 22 s on 2 threads); 0: none."""
    polish_steps: int = 6
    """Adam steps given to each neighbour before it is compared."""
    decide_steps: int = 0
    """Adam steps each value of a categorical parameter (``Generator.categorical``: buildings'
    roof type), and with ``decide_turns`` each value turned a quarter, gets at the previous
    stage's resolution before the last refinement stage; they are compared at that stage's
    resolution (``ipm.methods.diff.decide``); 0: none. 30 in the default profile: on the dev
    buildings (one view, 256 px, window masks, seeds 0 and 1; building_1 and building_d1-d3,
    d5-d8) the mean 64-view IoU went from 0.942 to 0.957, worst 0.784 either way; five quarter-turned
    fits came back (building_d5 seed 0, building_d7 and building_d8 both seeds: 0.936-0.978 ->
    0.991-0.995) and two wrong roofs (building_d5 seed 1 0.947 -> 0.986, building_d6 seed 1 0.884
    -> 0.973); where a low gable and a hip roof are within a few per cent in the loss, the pick
    can go the wrong way: building_d2 0.940 -> 0.911 and 0.951 -> 0.918, building_d3 seed 1
    0.945 -> 0.916."""
    decide_rounds: int = 1
    """Rounds of decide's race: after each, the better half of the candidates (at least two) get
    ``decide_steps`` more Adam steps from where they stand; 1: one round, the lowest loss wins.
    In one round the current roof, already converged, meets new ones still descending
    (building_d12 seed 0: a hip roof, the truth's, 0.00554 against the gable's 0.00510 after 30
    steps, 0.00495 against 0.00507 after 60). 3 in the default profile (6 -> 3 -> 2 candidates,
    330 steps instead of 180): dev buildings in family (building_1, building_d1-d12, seeds 0-1,
    26 runs) 0.962 -> 0.967 mean IoU (paired +0.0045, standard error 0.0020; 7 better, 1 worse),
    worst 0.777 -> 0.802; building_ext (out of family, seeds 0-7) 0.794 -> 0.787 (paired -0.006,
    standard error 0.005)."""
    decide_turns: bool = True
    """Whether decide also tries each value turned a quarter (width and depth traded, the counts
    the views show read in again) for a generator with a front (``Generator.marker``): one view
    without the door cannot tell a house's front from its side, but a gable's ridge can."""
    decide_least: bool = False
    """Whether a value decide tries starts the continuous parameters it turns on (and the current
    value had off) at their lower bounds: the new kind as near the old as it can be (a flat roof's
    unused roof height would otherwise start a gable at whatever height a preset left there; a
    hip's ratio at its least is the hip nearest a gable). Off: dev in family 0.975 -> 0.975
    (building_d17's flat fit finds its low gable, 0.955 -> 0.981), building_ext 0.796 -> 0.778
    (seeds 0-3; one seed's near-tie in the race flipped), README."""
    decide_shares: tuple[float, ...] = ()
    """Shares of the object's height that decide also tries giving to its roof, for each value
    of the categorical parameter (and each turned), where the generator splits it
    (``Generator.split_roof``: a pitched roof; the walls take the rest). One view shows where a
    low house's eaves meet its walls only through a kink in the outline: building_d24's tall hip
    roof over one storey fitted as a gable over walls twice as tall (64-view IoU 0.63; from that
    fit a hip at 0.6 of the height reached 0.0029 against 0.0068 in 60 steps), building_d29's
    one storey under a wide gable as two (0.84; 0.0027 against 0.0044). (): none. (0.3, 0.6) in
    the default profile: dev, seed 0, in family (building_1, building_d1-d42, 43 runs) 0.954 ->
    0.963 mean IoU (paired +0.009, standard error 0.010; worst 0.625 -> 0.792; d24 0.63 -> 0.97, d29
    0.84 -> 0.99, d33 0.81 -> 0.89; without d24 and d29, which the shares were chosen on, -0.003:
    two near-ties of the race went the other way, building_1 0.98 -> 0.89, d23 0.95 -> 0.79),
    building_ext (seeds 0-3) 0.796 -> 0.826 (paired +0.030, standard error 0.023)."""
    sight_steps: int = 0
    """Before the last refinement stage, for a generator with a ``footprint`` (buildings): that
    footprint's side the first view looks along is tried as it stands and times each of
    ``sight_factors`` (its near face held where it is), each start given this many Adam steps at
    the previous stage's resolution and compared at the last's; the lowest loss goes on, by a
    margin (``sight_margin``; ``ipm.methods.diff.sweep_sight``); 0: none. One view shows the
    extent along its line of sight only through a sliver of side wall and the roof's rise, and
    the fits settle where they start (building_1: depth 1.16-1.20 for the truth's 0.95, the
    truth's loss lower). 90 in the default profile: dev buildings in family (building_1,
    building_d1-d12, seeds 0-1, 26 runs) 0.967 -> 0.978 mean IoU (paired +0.011, standard error
    0.008; a stretch won 10 times: building_1 0.80 / 0.88 -> 0.99 / 0.97, five others up by
    0.003-0.007, three down by 0.002-0.006), worst 0.802 -> 0.914; building_ext (out of family,
    seeds 0-7) 0.787 -> 0.784 (paired -0.003, standard error 0.004)."""
    sight_factors: tuple[float, ...] = (0.7, 0.84, 1.19, 1.43)
    """The stretches ``sight_steps`` tries (about 18 % apart in the log)."""
    sight_margin: float = 0.05
    """A stretch replaces the extent as it stands only with a loss lower by more than this
    fraction: where the generator can make the object, the right extent removes most of what is
    left of the loss (dev in family, where a stretch won: 6-33 % lower), while on a shape it
    cannot make, another extent trades a per cent or two of a large remainder for nothing
    (building_ext: 0.2-1.6 % lower; with no margin a stretch won on all eight seeds and the
    64-view IoU went 0.787 -> 0.779, five seeds down by 0.002-0.033). Chosen on dev; with it no
    stretch wins on building_ext."""
    place_steps: int = 0
    """Before the last refinement stage, after ``sight_steps``, for a generator with
    ``placements`` (buildings: a chimney, mid-sized, at nine places on the roof): the fit as it
    stands and the fit with its small part put at each placement, each start given this many
    Adam steps at the previous stage's resolution and compared at the last's; the lowest loss goes
    on, by a margin (``place_margin``; ``ipm.methods.diff.sweep_place``); 0: none. A chimney covers
    a few hundred pixels of a view and gives no gradient where it is not drawn, so the memetic
    stage's placement stays (building_d4: a chimney 0.3 above the ridge in the view, the fits' a
    stub elsewhere; with the truth's chimney put into the fits, dev chimney fits 0.006-0.057
    higher in IoU). 40 in the default profile: dev in family (building_1, d2, d4, d12-d15, d17-d22,
    14 runs) 0.960 -> 0.964 mean IoU (paired +0.004, standard error 0.002; a place won 3 times:
    building_d4 0.966 / 0.964 -> 0.985 / 0.986, d15 0.968 -> 0.969; none lower by more than
    0.002); building_ext (out of family, seeds 0-7) 0.784 -> 0.785 (no place won)."""
    place_margin: float = 0.4
    """A placement replaces the part as it stands only with a loss lower by more than this
    fraction. Where the memetic stage left a chimney the view shows out, or as a stub elsewhere,
    the right place removes half of what is left of the loss (building_d4, both seeds: 53-54 %;
    IoU 0.96 -> 0.98); a chimney at a place where the view shows none, or one moved along the
    line of sight, lowers it by a third or less while the 64-view IoU falls (dev, 40 steps from the
    landed fits: building_d15 32 %, building_d12 13 % and 8 %, building_d2 6 %: IoU 0.002-0.007
    lower), since it patches another part's error or puts the chimney at a depth one view does not
    show. Chosen on dev."""
    recentre: bool = True
    """Before each refinement stage, trade the generator's lengths against the pose scale (the
    same mesh, :meth:`ipm.problem.Problem.recentred`) so that the lengths sit midway between
    their bounds: a fit that drifted to a small scale otherwise has its roof at its highest and
    bends the rest of the shape to make up for it (building_d18: scale 0.81 of the truth's, roof
    height, overhang and cornice at their upper bounds, the depth 12 % short; re-centred 0.932
    against 0.890). Dev, one view, seed 0: in family (building_1, d1-d22) 0.973 -> 0.975 (paired
    +0.002, standard error 0.002; 5 up and 2 down by more than 0.002), building_ext (seeds 0-3)
    0.781 -> 0.796; seed 1 of d18 0.931 -> 0.911, where no length was at a bound. Most fits have
    lengths at both bounds and are left as they are."""
    focal_sweep: int = 0
    """For a camera whose field of view is unknown (``ipm.photo``): before the last refinement
    stage, the focal gene is held at the estimate's and at this many points on either side,
    ``focal_step`` apart in log focal length, walking outwards, the rest refined under each for
    ``focal_steps`` Adam steps at that stage's resolution; the lowest loss wins
    (``ipm.methods.diff.sweep_focal``); 0: none. The default profile's 3 x 100 steps, dev cups
    with the camera withheld (seed 0): field-of-view error cup_1 +43 % -> +7.5 %, cup_2 +17 % ->
    -2.4 %; pitch error +4.4 -> +0.5 and -5.8 -> -7.3 degrees. With 30 steps a point the
    profile drowned in the steps' lag and render noise (cup_1 +52 %)."""
    pitch_bins: int = 1
    """For an unknown camera (``ipm.photo``): the memetic stage keeps the best individual per
    topology, yaw bin and one of this many bins of the camera's pitch over ``PITCH_PRIOR``
    (``ipm.methods.diff.pitch_niche``), so that starts at other elevations are not merged away
    once the population agrees on the yaw; 1 (every profile): no pitch bins. Not a default: the
    final loss showed the withheld camera's fits missing the true camera's basin (dev, seed 0,
    JAX renderer: cup_1 0.00140 against 0.00081 with the camera given, cup_2 0.00089 / 0.00049,
    cup_d2 0.00335 / 0.00054), and 4 bins rescued those three (world IoU 0.12 -> 0.81, 0.13 ->
    0.41, 0.05 -> 0.53), but over dev cups cup_1, cup_2, cup_d1, cup_d2, cup_ext x seeds 0-2
    (JAX) the mean went 0.466 -> 0.523 with 7 runs better and 7 worse (paired difference +0.057,
    standard error 0.067), and the path's default renderer, Mitsuba, was not run with it."""
    pitch_starts: tuple[float, ...] = ()
    """For an unknown camera whose field of view is given (``ipm.photo``: ``--fov`` or the photo's
    Exif): after the usual memetic stage (its starts spread over the pitch prior) it is run once
    more per pitch given here (degrees), the camera's pitch held at it, and the finalists are
    drawn from all these runs' last generations (the pitch set free from polish on); () (the
    smoke profile): the usual stage alone. With the pitch held through a whole fit, the truth's
    pitch has the lowest final loss (dev, field of view given, seed 0: cup_2 0.00094 / 0.00049 /
    0.00269 at 18.6 (the free fit's) / 25 (the truth) / 31 degrees; cup_d1 0.00120 / 0.00076 /
    0.00291 at 15.9 / 22.5 / 29), while the free fit settles 6-7 degrees low. The default
    profile's four pitches, dev cups, field of view given, JAX, seeds 0-1: world IoU 0.625 ->
    0.784 (10 runs, 6 better, none worse; README); with the field of view withheld too no better
    (15 runs, 0.466 -> 0.474, 8 better, 6 worse: the field of view's own ambiguity dominates), so
    there it stays off."""
    focal_step: float = 0.1
    """Grid step of ``focal_sweep`` in log focal length (0.1: about 10 % in focal length)."""
    focal_steps: int = 100
    """Adam steps each point of ``focal_sweep`` gets, starting from its inner neighbour's result."""
    pitch_sweep: int = 0
    """With ``focal_sweep``, after it: the camera's pitch held at the estimate's and at this many
    points on either side, ``pitch_step`` degrees apart, walked the same way (``focal_steps``
    each; ``ipm.methods.diff.sweep_focal``); 0: none. The default profile's 2 x 0.25 degrees, dev,
    camera and field of view withheld, seed 0 (rule written before the runs: buildings d1-d4
    paired >= +0.01, cups cup_1 and cup_2 >= -0.01): world IoU d1-d4 0.974 / 0.863 / 0.926 / 0.868
    -> 0.968 / 0.873 / 0.995 / 0.887 (paired +0.023), cup_1 0.499 -> 0.549, cup_2 0.169 -> 0.177.
    With the field of view given (``pitch_starts``) not measured, so not run there. A coarse walk
    as well (4 points either side, 2 degrees apart, at the memetic resolution after the polish, for
    the cups' memetic stage settling 6-10 degrees low) failed its rule (dev cups, seed 0, paired
    world IoU >= +0.05): cup_1 / cup_2 / cup_d1 / cup_d2 0.549 / 0.177 / 0.244 / 0.018 -> 0.539 /
    0.148 / 0.426 / 0.028 (+0.039; cup_d2's shape IoU 0.67 -> 0.31): with the focal length free
    the walked losses differ by a few per cent and by noise, so it was removed."""
    pitch_step: float = 0.25
    """Grid step of ``pitch_sweep`` in degrees."""
    fov_grid: tuple[float, ...] = ()
    """For a camera whose field of view is unknown (``ipm.photo``): instead of estimating it,
    fit once per field of view given here (horizontal, degrees) as if it were given (pitch starts,
    the focal length held; ``ipm.methods.diff.fit_fov_grid``) and keep the fit of lowest loss at
    the last refinement resolution; () (every profile): the field of view estimated in one fit.
    With the focal length free the loss is nearly flat along focal length and pitch together, and
    the cups' fits settle 6-10 degrees low; with it held, even a wrong one, the pitch's basin is
    distinct (dev, field of view given 0.7-1.4 x the truth's focal length, seed 0: the lowest loss
    of five within 1.4 degrees of the truth's pitch on cup_1, cup_2, cup_d1, cup_d2). With
    ``ipm.photo.FOV_GRID`` (rule written before the runs: dev cups, seed 0, paired world IoU >=
    +0.05 and a lower mean pitch error): cup_1 / cup_2 / cup_d1 / cup_d2 world IoU 0.549 / 0.177 /
    0.244 / 0.018 -> 0.890 / 0.297 / 0.434 / 0.537, pitch error 1.3 / 6.8 / 5.9 / 9.8 -> 0.3 / 1.7
    / 1.1 / 0.9 degrees; passed. Seed 1 went the other way (0.501 / 0.903 / 0.677 / 0.895 ->
    0.498 / 0.311 / 0.635 / 0.929): over both seeds paired +0.071, standard error 0.116, pitch
    within 3 degrees on 7 of 8 runs against 5 of 8. The field of view itself is barely told (the
    loss is nearly flat over it; cup_2 seed 1 picked 70 degrees, +77 %). Not a default: within the
    noise on world IoU, six fits' time, and the buildings were not run with it (README)."""
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
    """Silhouette renderer: ``jax`` (``ipm.render.edges``: scanline coverage and edge-sampling
    gradients at the scanlines' boundary crossings, one compiled function with the generator; a
    class mask too, by a z-buffer per sample), ``mitsuba`` (``ipm.render.silhouette``), or ``auto``
    (the default): jax, but Mitsuba for an unknown camera whose field of view is estimated
    (``ipm.photo``: its focal sweep was tuned with Mitsuba, not yet validated with JAX on dev).
    Dev cups, one view, default profile, seeds 0-1: mean IoU jax 0.925, Mitsuba 0.914 (per case
    in the README), a cup in a fifth of the time. Dev buildings with window masks (one view,
    seeds 0 and 1 in family, 0-7 on building_ext): in family 0.962 against 0.965 (26 runs,
    paired difference -0.003, standard error 0.007), building_ext 0.794 against 0.820 (8 runs
    each, standard deviations 0.09: some seeds of either end 15-25 degrees off in yaw, 4 of 8
    with JAX, 2 of 8 with Mitsuba), a building in 0.39 x Mitsuba's time (README)."""
    memetic_batch: bool = False
    """Evaluate the memetic population's steps a round at a time, one batched call of the JAX
    renderer per topology (``ipm.optim.memetic.adam_steps_together``: the same seeds, so the same
    fit up to a batched program's float rounding). Off: it did not pay where measured
    (``bench/RESULTS.md``): on a CPU a batch costs its size in single calls, and on one H200 a
    default-profile cup's single call costs 3.3 ms, a padded batch of 4 about 4.2 ms and of 16
    about 7.5 ms, while the rounds are 270-370 against 910 single calls (the budget goes mostly to
    the best few individuals). Only silhouettes are batched; class masks run one at a time."""
    window_weight: float = 1.0
    """Weight of the class-mask term beside the silhouette (the generator's ``mask_class``:
    buildings' windows; used when the views have semantic images); 0 = the silhouette alone."""
    extra_class_weight: float = 0.0
    """Weight of the class-mask term of each of the generator's ``extra_mask_classes`` (buildings:
    roof; the same pyramid and loss as the windows'); 0 = none. Off: at 1 the dev buildings in
    family went 0.975 -> 0.974 (building_d17's low gable found, 0.955 -> 0.981) and building_ext,
    two row houses the generator cannot make, 0.796 -> 0.594 (seeds 0-3; 0.741 at 0.1), README."""
    window_levels: int = 4
    """Levels of the 2 x 2 mean pyramid over which the class-mask term is averaged (1: the
    full-resolution MSE alone)."""
    window_loss: str = "mse"
    """Loss of the class-mask term on each pyramid level: ``mse`` or ``dice``
    (``ipm.render.silhouette._pyramid_loss``; ``dice`` wants a weight of about 0.01)."""
    max_tilt: float = 0.0
    """Bound of the two tilt angles (radians). 0 holds the object upright, as the scene convention
    has it (DESIGN.md): from one view a tilt of a few degrees trades against the profile's shape
    (default profile, one view: cup_2 IoU 0.930 with tilts up to 0.1, 0.986 upright). Raise it for
    objects that may lean."""


PROFILES = {
    "paper": DiffProfile(),
    # default: the memetic stage was 12 x 8 x 48; this one took cup_ext (one view, seed 0) from
    # 0.906 to 0.914 for about 30 s more per single-view cup. The last stage was 60 steps: 300 let a
    # slow drift finish (a building's depth along the line of sight, README), dev seed 0: buildings
    # in family 0.963 -> 0.969 (43 runs, paired +0.006, SE 0.002), cups +0.006, building_ext -0.003.
    # A photo's pitch is walked after its focal length (pitch_sweep, dev: README)
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
