"""Losses for the non-differentiable (genetic) search, registered by name.

``LOSSES["tree_similarity"]`` is :func:`ipm.losses.tree.tree_loss`: one minus the paper's tree
similarity ``TSim`` of two semantic label images times its regularisation multipliers, a value in
[0, 1] to minimise (0 = identical).
"""
from ipm.losses import tree  # noqa: F401  (fills the registry)
from ipm.losses.registry import LOSSES
from ipm.losses.tree import (
    REGULARISERS, StripeFeatures, TreeStats, loss_terms, regularisation_multipliers, stripe_features,
    tree_loss, tree_similarity,
)

__all__ = [
    "LOSSES", "REGULARISERS", "StripeFeatures", "TreeStats", "loss_terms", "regularisation_multipliers",
    "stripe_features", "tree_loss", "tree_similarity",
]
