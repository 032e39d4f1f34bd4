"""The search loop's extension points: a move a generator lists runs where its phase says, with its
own settings, and the start of the search is pluggable."""
from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Annotated

import numpy as np
import pytest

from ipm.errors import UserError
from ipm.generators.dishes import Dishes
from ipm.io.views import Views
from ipm.problem import Problem
from ipm.profiles import get_profile
from ipm.render.cameras import orbit_camera
from ipm.render.silhouette import SilhouetteRenderer
from ipm.search.loop import reconstruct
from ipm.search.moves import MOVES, Move, moves_for, register
from ipm.search.starts import preset_start
from ipm.settings import Settings, at_least


@dataclass(frozen=True)
class NudgeSettings(Settings):
    """Settings of the toy move."""

    KIND = "diff setting"
    nudge_steps: Annotated[int, at_least(0)] = 2
    """Adam steps of the nudged start."""


CALLS: list[dict] = []


@register
class Nudge(Move):
    """A toy move: before the last stage, race each candidate against itself turned a little."""

    name, phase, settings, steps_before = "nudge", "last", NudgeSettings, True

    def cost(self, problem, profile) -> int:
        return 2 * profile.of(NudgeSettings).nudge_steps

    def __call__(self, cand, trial, settings):
        CALLS.append({"steps": trial.steps.width, "score": trial.score.width, "settings": settings})
        turned = cand.z.copy()
        turned[trial.problem.n_shape] += 0.1
        cand.z = trial.race(cand.z, "nudge kept", [("nudge turned", trial.problem.clip(turned))],
                            settings.nudge_steps, 0.0, trial.scorer((1, 2)))
        return cand


@register
class Idle(Move):
    """A toy move that spends evaluations (steps and scores) and keeps every candidate as it was."""

    name, phase = "idle", "last"  # its steps at the width of the Adam run after it

    def __call__(self, cand, trial, settings):
        trial.tried(cand.z, "idle", 3, trial.scorer((5, 6)))
        return cand


@register
class Fork(Move):
    """A toy finalist move: each finalist forks into itself and a twin turned a little and credited
    with a loss of 1 (the way the door's reading forks a building)."""

    name, phase = "fork", "finalist"

    def __call__(self, cand, trial, settings):
        twin = replace(cand, z=cand.z.copy(), credit=1.0)
        twin.z[trial.problem.n_shape] += 0.3
        return [cand, twin]


class ToyCups(Dishes):
    """The cups generator with the toy move in its list."""

    moves = ("polish", "nudge")


@pytest.fixture(scope="module")
def mug_view(mitsuba_cpu):
    """A mug seen from one side (a Mitsuba mask), and the toy generator's problem."""
    gen = ToyCups()
    problem = Problem(gen, np.zeros(3), 1.0)
    z = problem.initial_z(gen.spec.to_unit(gen.presets["mug"]), 0.5)
    cam = orbit_camera([0, 0.3, 0], 3.0, 30.0, 20.0)[None]
    truth = problem.world_mesh(z, 0)
    masks = SilhouetteRenderer(cam, 0.7, 48, 48, spp=8).render(truth.vertices, truth.faces) > 0.5
    return problem, Views(0.7, 48, 48, cam, masks.astype(np.float32))


@pytest.mark.slow
def test_a_listed_move_runs_in_its_phase_with_its_settings(mug_view):
    problem, views = mug_view
    assert [m.name for m in moves_for(problem)] == ["polish", "nudge"]
    profile = get_profile("smoke", nudge_steps=3, refine_res=(32, 48), refine_iterations=(2, 2))
    CALLS.clear()
    z, trace = reconstruct(problem, views, profile, seed=0, progress=False)
    assert len(CALLS) == 1  # before the last stage only, on the one candidate left
    assert CALLS[0] == {"steps": 32, "score": 48, "settings": NudgeSettings(nudge_steps=3)}
    rows = trace[trace["stage"] == "nudge"]
    assert set(rows["origin"]) == {"nudge kept", "nudge turned"}
    assert (rows["res"] == 32).sum() == 2 * 3 and (rows["res"] == 48).sum() == 2  # the steps, then the scores
    assert np.all(np.isfinite(z))
    with pytest.raises(UserError, match="nudge_steps must be >= 0"):
        get_profile("smoke", nudge_steps=-1)


@pytest.mark.slow
def test_an_unlisted_move_does_not_run(mug_view):
    problem, views = mug_view
    plain = Problem(Dishes(), problem.anchor_t, problem.anchor_s)
    assert "nudge" in MOVES and "nudge" not in [m.name for m in moves_for(plain)]
    CALLS.clear()
    reconstruct(plain, views, get_profile("smoke"), seed=0, progress=False)
    assert CALLS == []


@pytest.mark.slow
def test_a_move_that_changes_nothing_leaves_the_fit_as_it_was(mug_view):
    """The render seeds a stage or move draws do not follow the evaluations made before it: a move
    that spends evaluations but keeps its candidate gives the fit of a search without it."""
    problem, views = mug_view

    class Idling(Dishes):
        moves = Dishes.moves + ("idle",)

    profile = get_profile("smoke", refine_res=(32, 48), refine_iterations=(3, 3))
    fits = [reconstruct(Problem(gen, problem.anchor_t, problem.anchor_s), views, profile, seed=0, progress=False)
            for gen in (Dishes(), Idling())]
    assert (fits[1][1]["stage"] == "idle").sum() == 3 + 1  # it ran: three steps and a score
    np.testing.assert_array_equal(fits[0][0], fits[1][0])


@pytest.mark.slow
def test_a_forked_finalist_s_twins_race_through_the_first_stage(mug_view):
    """A finalist move may return several candidates: each is refined through the first stage, and
    between twins the finalists' choice takes a twin's credit off its loss."""
    problem, views = mug_view

    class Forking(Dishes):
        moves = ("fork",)

    profile = get_profile("smoke", refine_res=(32, 48), refine_iterations=(2, 3), refine_candidates=1)
    z, trace = reconstruct(Problem(Forking(), problem.anchor_t, problem.anchor_s), views, profile, seed=0,
                           progress=False)
    refine = trace[trace["stage"] == "refine"]
    assert (refine["res"] == 32).sum() == 2 * 3 and (refine["res"] == 48).sum() == 3 + 1  # both twins, then one
    chosen = trace[trace["stage"] == "choose"]
    assert list(chosen["origin"]) == ["finalist 0", "finalist 1, twin credited 1.00000",
                                      "finalist 0 left: its twin's loss less its credit is lower"]
    assert 0.0 < chosen["loss"].iloc[1] < 1.0  # the loss as scored; the credit decides between the twins
    assert np.all(np.isfinite(z))


@pytest.mark.slow
def test_the_start_of_the_search_is_pluggable(mug_view):
    """A start other than the presets' (here: the mug preset alone, as a learned proposal would
    give one guess) feeds the memetic stage unchanged."""
    problem, views = mug_view
    starts = []

    def one_guess(problem, settings, rng, prepare):
        pop = preset_start(problem, settings, rng, prepare)
        for ind in pop:
            ind.origin = "guess"
        starts.append(len(pop))
        return pop

    _, trace = reconstruct(problem, views, get_profile("smoke"), seed=0, progress=False, start=one_guess)
    assert starts == [get_profile("smoke").memetic.population]
    memetic = trace[trace["stage"] == "memetic"]
    assert "guess" in set(memetic["origin"]) and not {"mug", "random"} & set(memetic["origin"])


def _mug_facing(problem, yaw_towards: float, cam: np.ndarray) -> np.ndarray:
    """The mug preset with its handle turned ``yaw_towards`` radians from the vertical plane across
    the line of sight, towards the camera."""
    gen = problem.generator
    z = problem.initial_z(gen.spec.to_unit(gen.presets["mug"]), 0.0)
    to_cam = cam[:3, 3] - problem.to_world(z)(np.zeros((1, 3)))[0]
    z[problem.n_shape] = -np.arctan2(to_cam[2], to_cam[0]) + yaw_towards  # R_y(yaw) e_x at azimuth -yaw
    return problem.clip(z)


def test_the_mirror_turns_the_handle_through_the_plane_across_the_line_of_sight():
    from ipm.search.moves.handle import mirrored_yaw

    problem = Problem(Dishes(), np.zeros(3), 1.0)
    cam = orbit_camera([0, 0.3, 0], 3.0, 40.0, 15.0)
    for turn in (0.3, 1.2, -0.7):
        z = _mug_facing(problem, turn, cam)
        alt = mirrored_yaw(problem, z, cam)
        x = [problem.to_world(w)(np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]])) for w in (z, alt)]
        (o, h), (_, h2) = x
        v = cam[:3, 3] - o
        v[1] = 0.0
        v /= np.linalg.norm(v)
        assert np.isclose((h2 - o) @ v, -((h - o) @ v), atol=1e-5)  # towards the camera <-> away
        side = np.cross(v, [0.0, 1.0, 0.0])
        assert np.isclose((h2 - o) @ side, (h - o) @ side, atol=1e-5)  # the outline's side kept
        assert np.allclose(alt[: problem.n_shape], z[: problem.n_shape])
        back = mirrored_yaw(problem, alt, cam)[problem.n_shape]
        assert np.isclose(np.angle(np.exp(1j * (back - z[problem.n_shape]))), 0.0, atol=1e-6)


def test_the_image_shading_tells_the_handle_s_side_and_turn(mitsuba_cpu):
    """Shaded images of a mug whose handle is turned towards the camera (drawn over the body) or
    away from it (hidden): of the truth, its mirror (the same outline) and the truth turned by 15 or
    30 degrees either way, the truth's surface shades most like the image; the candidates are
    compared on the pixels they all cover, inside the mask's rim."""
    from ipm.search.moves.handle import LUMINANCE, mirrored_yaw, shading_residuals, surface_maps

    problem = Problem(Dishes(), np.zeros(3), 1.0)
    cam = orbit_camera([0, 0.4, 0], 3.0, 0.0, 10.0)
    res, fov = 96, 0.7
    views = Views(fov, res, res, cam[None])
    light = np.array([0.4, 0.8, 0.45]) / np.linalg.norm([0.4, 0.8, 0.45])
    for turn in (0.6, -0.4, np.pi - 1.1):
        truth = _mug_facing(problem, turn, cam)
        normals, part = surface_maps(problem, truth, 1, views)
        assert (part == problem.generator.part_names.index("handle")).any()
        albedo = np.where(part == problem.generator.part_names.index("handle"), 0.6, 0.9)
        shade = np.where(part >= 0, albedo * (0.15 + 0.8 * np.clip(normals @ light, 0.0, None)), 0.0)
        photo = np.repeat(shade[..., None], 3, axis=2)
        others = [mirrored_yaw(problem, truth, cam)] + [problem.turned(truth, np.radians(d)) for d in (-30, -15, 15, 30)]
        maps = [surface_maps(problem, z, 1, views) for z in [truth] + others]
        residuals = shading_residuals(photo @ LUMINANCE, (part >= 0).astype(float), maps)
        assert residuals[0] < min(residuals[1:]), (turn, residuals)


def test_the_progress_bar_plans_every_phase_s_moves_on_the_candidates_it_sees(mug_view):
    """The planned evaluations count a move's cost once per candidate its phase sees: the
    finalists' moves and the first stage's on every finalist, the later stages' on the one left,
    the last and end phases' once."""
    from ipm.search.loop import planned_evaluations
    from ipm.search.moves import PHASES

    class Costly(Move):
        def __init__(self, phase, n):
            self.phase, self.n = phase, n

        def cost(self, problem, profile):
            return self.n

    problem, _ = mug_view
    profile = get_profile("smoke", refine_candidates=3, refine_res=(32, 48), refine_iterations=(2, 5))
    none = {p: [] for p in PHASES}
    base = planned_evaluations(problem, profile, profile.memetic, none, 1)
    mem = profile.memetic
    assert base == mem.ga_iterations * (mem.adam_per_iteration + mem.population) + 3 * (2 + 1) + (5 + 1)
    seen = {"finalist": 3, "stage": 3 + 1, "refine": 3 + 1, "last": 1, "end": 1}
    for name, k in seen.items():
        assert planned_evaluations(problem, profile, mem, {**none, name: [Costly(name, 7)]}, 1) == base + 7 * k, name
    assert planned_evaluations(problem, profile, mem, none, 2) == base + mem.ga_iterations * (
        mem.adam_per_iteration + mem.population)


@pytest.mark.slow
def test_tries_side_by_side_give_the_fit_of_one_after_another(mug_view, monkeypatch):
    """On two threads the memetic stage's individuals, polish's neighbours and a race's starts run
    side by side (``ipm.lanes``), with the point, the trace and the render seeds of one thread."""
    import threading

    import ipm.lanes as lanes
    import ipm.search.loop as loop

    problem, views = mug_view
    profile = get_profile("smoke", population=6, nudge_steps=3, refine_res=(32, 48), refine_iterations=(2, 2))
    on_lanes, run = [], lanes._run
    monkeypatch.setattr(lanes, "_run", lambda *a: on_lanes.append(threading.current_thread().name) or run(*a))
    fits = []
    for n in (1, 2):
        monkeypatch.setattr(loop, "thread_count", lambda: n)
        fits.append(reconstruct(Problem(ToyCups(), problem.anchor_t, problem.anchor_s), views, profile, seed=0,
                                progress=False))
    (z1, trace1), (z2, trace2) = fits
    assert np.array_equal(z1, z2)
    assert trace1.drop(columns="seconds").equals(trace2.drop(columns="seconds"))
    assert {"memetic", "polish", "nudge"} <= set(trace2["stage"])
    assert len(on_lanes) > 10 and {name.startswith("lane") for name in on_lanes} >= {True}
