"""``[learning]`` of ``dynid identify``: a physics-informed recurrent network learns what the
identified model leaves in the training torques (paper 003, Section 3.4; :mod:`dynid.learning`).

All keys optional; the section's presence switches the network on:
    ``model``: ``"lstm"`` (default), ``"gru"`` or ``"rnn"`` (the ablation of paper 003, Table 1);
    ``window``: the input sequence length k (default 6; paper: 5-8 control cycles);
    ``hidden``: hidden units of the one recurrent layer (default 24; 4-256);
    ``epochs``: the most training epochs (default 150);
    ``lambda``: weight of the physical loss terms (default 0.2; paper: 0.1-0.3, enforced);
    ``seed``: weights and shuffling (default 0);
    ``max_seconds``: wall-clock bound of the whole training (default 120);
    ``patience``: epochs without a better validation error before stopping (default 20);
    ``learning_rate`` (default 5e-3), ``batch_size`` (default 128);
    ``validation_fraction``: the share of the training samples, in interleaved blocks spread over the log,
    kept for early stopping (default 0.2);
    ``stribeck_velocity``: v_s of the Stribeck prior feature, one value or one per joint [rad/s]
    (default: fitted to the training log's friction).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from dynid.config._schema import _int, _num, _num_or_list, _str, _table
from dynid.errors import ConfigError
from dynid.learning import MODELS, LearningConfig

__all__ = ["parse_learning", "LEARNING_KEYS"]

LEARNING_KEYS = {"model", "window", "hidden", "epochs", "lambda", "seed", "max_seconds", "patience", "learning_rate",
                 "batch_size", "validation_fraction", "stribeck_velocity"}


def parse_learning(t: Mapping[str, Any] | None) -> LearningConfig | None:
    """``[learning]`` -> :class:`~dynid.learning.LearningConfig` (None when the section is absent)."""
    if t is None:
        return None
    w = "learning"
    t = _table(dict(t) if isinstance(t, Mapping) else t, w, LEARNING_KEYS)
    d = LearningConfig()
    lam = _num(t.get("lambda", d.lam), f"{w}.lambda")
    if not 0.1 <= lam <= 0.3:
        raise ConfigError(f"{w}.lambda: must be in [0.1, 0.3] (paper 003, Sec. 3.4), got {lam!r}")
    window = _int(t.get("window", d.window), f"{w}.window", 1)
    if window > 64:
        raise ConfigError(f"{w}.window: at most 64 samples, got {window}")
    hidden = _int(t.get("hidden", d.hidden), f"{w}.hidden", 4)
    if hidden > 256:
        raise ConfigError(f"{w}.hidden: at most 256 units, got {hidden}")
    frac = _num(t.get("validation_fraction", d.validation_fraction), f"{w}.validation_fraction", True)
    if not frac < 0.5:
        raise ConfigError(f"{w}.validation_fraction: must be below 0.5, got {frac!r}")
    vs = None
    if "stribeck_velocity" in t:
        v = _num_or_list(t["stribeck_velocity"], f"{w}.stribeck_velocity", True)
        vs = tuple(float(x) for x in (v if isinstance(v, tuple) else (v,)))
    return LearningConfig(
        model=_str(t.get("model", d.model), f"{w}.model", MODELS),
        window=window,
        hidden=hidden,
        epochs=_int(t.get("epochs", d.epochs), f"{w}.epochs", 1),
        lam=lam,
        seed=_int(t.get("seed", d.seed), f"{w}.seed", 0),
        max_seconds=_num(t.get("max_seconds", d.max_seconds), f"{w}.max_seconds", True),
        patience=_int(t.get("patience", d.patience), f"{w}.patience", 1),
        learning_rate=_num(t.get("learning_rate", d.learning_rate), f"{w}.learning_rate", True),
        batch_size=_int(t.get("batch_size", d.batch_size), f"{w}.batch_size", 1),
        validation_fraction=frac,
        stribeck_velocity=vs,
    )
