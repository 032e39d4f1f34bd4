"""The preparations shipped with the package (``python -m ipm.ship``): what the default workflow
reads instead of training in the run, so its learned rows are the same on every kind of CPU."""
from __future__ import annotations

import json
from dataclasses import asdict

import pytest

from ipm.errors import UserError
from ipm.methods import METHODS
from ipm.ship import SHIPPED, ship, shipped_names


def _budget(method: str) -> dict:
    """The default profile's settings of a method's preparation, as its file records them."""
    if method in ("learned", "learned_photo"):
        from ipm.learned.train import TRAIN_PROFILES

        return asdict(TRAIN_PROFILES["default"])
    from baselines.occnet import PROFILES

    return asdict(PROFILES["default"])


@pytest.mark.parametrize("name", shipped_names())
def test_every_shipped_preparation_is_there_and_is_the_default_profiles_seed_0(name):
    """A file per entry of ``SHIPPED``, where the catalogue says, for the right generator; a
    network's made with the default budget from seed 0 (a changed budget without new files fails
    here), the GA's statistics from the default profile's sample count."""
    method, _, generator = name.partition("/")
    path = METHODS[method].shipped_file(generator)
    assert path is not None, f"{name}: nothing at {METHODS[method].shipped_path(generator)} (python -m ipm.ship {name})"
    record = json.loads(path.read_text())
    if method == "ga":
        from ipm.optim.ga_settings import get_settings
        from ipm.optim.ga_statistics import GeneStatistics

        stats, settings = GeneStatistics.load(path), get_settings("default")
        assert (stats.n_samples, stats.h, stats.good_fraction, stats.prior) == (
            settings.stats_samples, settings.stats_h, settings.good_fraction, settings.stats_prior)
        return
    assert record["generator"] == generator and record["seed"] == 0
    assert record["settings"] == _budget(method)
    assert record.get("camera_hidden", False) == (method == "learned_photo")


def test_only_methods_with_a_preparation_ship_one_and_unknown_names_are_refused(tmp_path):
    assert all(METHODS[m].prepare_entry and METHODS[m].shipped for m in SHIPPED)
    assert all(METHODS[m].shipped is None for m in METHODS.names() if METHODS[m].prepare_entry is None)
    with pytest.raises(UserError, match="unknown shipped preparation 'occnet/trees'"):
        ship("occnet/trees")
