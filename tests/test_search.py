"""The search loop's extension points: a move a generator lists runs where its phase says, with its
own settings, and the start of the search is pluggable."""
from __future__ import annotations

from dataclasses import dataclass
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
