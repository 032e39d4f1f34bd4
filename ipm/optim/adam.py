"""Adam as a pair of pure functions over an explicit state (optax style), plus step rejection."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class AdamState:
    """First and second moment estimates and the step count."""

    m: np.ndarray
    v: np.ndarray
    t: int


def adam_init(z: np.ndarray) -> AdamState:
    return AdamState(np.zeros_like(z, np.float64), np.zeros_like(z, np.float64), 0)


def adam_update(state: AdamState, grad: np.ndarray, lr: float | np.ndarray,
                b1: float = 0.9, b2: float = 0.999, eps: float = 1e-8) -> tuple[np.ndarray, AdamState]:
    """The step to add to the parameters, and the new state (bias-corrected Adam)."""
    t = state.t + 1
    m = b1 * state.m + (1 - b1) * grad
    v = b2 * state.v + (1 - b2) * grad * grad
    step = -lr * (m / (1 - b1**t)) / (np.sqrt(v / (1 - b2**t)) + eps)
    return step, AdamState(m, v, t)
