"""One mechanism checks every group of settings: from the field types, with one line naming the setting."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Annotated, Literal

import pytest

from ipm.errors import UserError
from ipm.optim.ga_settings import GASettings
from ipm.profiles import get_profile, owner_of
from ipm.settings import UNIT, Range, Settings, at_least


@dataclass(frozen=True)
class Example(Settings):
    KIND = "example setting"
    count: Annotated[int, at_least(1)] = 2
    share: Annotated[float, UNIT] = 0.5
    step: Annotated[float, Range(0.0, open_lo=True)] = 0.1
    kind: Literal["a", "b"] = "a"
    on: bool = True
    widths: tuple[Annotated[int, at_least(8)], ...] = (16, 32)
    limit: int | None = None


@pytest.mark.parametrize("overrides, message", [
    ({"count": 0}, "example setting count must be >= 1, got 0"),
    ({"count": 2.5}, "example setting count must be an integer, got 2.5"),
    ({"count": True}, "example setting count must be an integer, got True"),
    ({"share": 1.5}, "example setting share must be >= 0 and <= 1, got 1.5"),
    ({"share": float("nan")}, "example setting share must be a finite number, got nan"),
    ({"step": 0.0}, "example setting step must be > 0, got 0.0"),
    ({"kind": "c"}, "unknown kind 'c' (known: a, b)"),
    ({"on": 1}, "example setting on must be true or false, got 1"),
    ({"widths": 16}, "example setting widths must be a list, got 16"),
    ({"widths": [16, 4]}, "example setting widths must be >= 8, got 4"),
    ({"limit": "x"}, "example setting limit must be an integer, got 'x'"),
    ({"cuont": 3}, "unknown example setting(s) cuont (known: count, kind, limit, on, share, step, widths)"),
])
def test_a_bad_value_or_name_is_one_line_naming_the_setting(overrides, message):
    with pytest.raises(UserError) as info:
        Example().updated(**overrides)
    assert str(info.value) == message


def test_good_values_pass_and_lists_become_tuples():
    s = Example().updated(count=3, share=1, widths=[8, 64], limit=None, kind="b")
    assert (s.count, s.share, s.widths, s.limit, s.kind) == (3, 1, (8, 64), None, "b")
    assert Example(limit=4).limit == 4 and Example() == Example()


def test_every_group_of_the_diff_path_and_the_ga_uses_it():
    """Every setting of a profile has one owner and each owner is a ``Settings``; a config's flat
    names reach their owner, and the GA's settings refuse what the diff path's refuse."""
    owners = set(owner_of().values())
    assert all(issubclass(cls, Settings) for cls in owners) and issubclass(GASettings, Settings)
    profile = get_profile("default", sight_steps=5, population=8, spp=2, refine_candidates=2)
    assert profile.as_dict()["sight_steps"] == 5 and profile.memetic.population == 8
    assert profile.objective.spp == 2 and profile.loop.refine_candidates == 2
    with pytest.raises(UserError, match="diff setting population must be >= 1, got 0"):
        get_profile("smoke", population=0)
    with pytest.raises(UserError, match="GA setting budget must be >= 1, got 0"):
        GASettings(budget=0)
    with pytest.raises(UserError, match="refine_res and refine_iterations need one entry per stage each"):
        get_profile("smoke", refine_res=(48, 96))
