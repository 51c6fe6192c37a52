"""The kernels' rows (:mod:`ineid.identify.rows`): the entries stacked in one operation, bit for bit as one by one."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from ineid.identify.rows import RowLayout, channel_rows, stacked_entries


def _entries(rng, n_axes: int, n_cols: int, batch):
    """Traced-like entries: arrays of the batch shape, structural zeros and other Python numbers mixed."""
    kinds = rng.integers(0, 4, n_axes * n_cols)
    return tuple(
        0 if k == 0 else (1 if k == 1 else (-2.5 if k == 2 else jnp.asarray(rng.normal(size=batch)))) for k in kinds
    )


def _reference(layout: RowLayout, entries, n_axes: int, batch, mask):
    """The rows entry by entry: each broadcast, cast, masked, then stacked (n_a, Cc, r, Fc)."""
    n = layout.n_cols

    def entry(a, c):
        return jnp.broadcast_to(entries[a * n + c], batch).astype(jnp.float64) * mask

    return jnp.stack([jnp.stack([entry(a, c) for c in layout.columns], axis=1) for a in range(n_axes)])


def test_channel_rows_equal_the_entries_one_by_one():
    rng = np.random.default_rng(3)
    n_axes, n_cols, batch = 3, 20, (2, 7)
    entries = _entries(rng, n_axes, n_cols, batch)
    mask = jnp.asarray((rng.uniform(size=batch) > 0.3).astype(np.float64))
    layout = RowLayout((), n_cols, (0, 3, 4, 9, 12, 19), (1, 2, 5), (), 0, False, ())
    theta_known = jnp.asarray(rng.normal(size=3))
    w, known = jax.jit(lambda m: channel_rows(layout, entries, n_axes, batch, m, theta_known, jnp.float64))(mask)
    assert w.shape == (n_axes, 2, len(layout.columns), 7)
    assert np.array_equal(np.asarray(w), np.asarray(_reference(layout, entries, n_axes, batch, mask)))
    assert known.shape == (n_axes, 2, 7)


def test_stacked_entries_is_one_concatenate_whatever_the_count():
    """Traced entries and structural zeros (what the generated regressors give): no operation per entry."""
    rng = np.random.default_rng(4)
    batch = (1, 5)
    arrays = [rng.normal(size=batch) for _ in range(400)]
    zero = rng.uniform(size=400) < 0.5

    def stacked(*xs):
        it = iter(xs)
        return stacked_entries([0 if z else next(it) for z in zero], batch, jnp.float64)

    names = [e.primitive.name for e in jax.make_jaxpr(stacked)(*arrays[: np.sum(~zero)]).eqns]
    assert names.count("concatenate") == 1 and len(names) < 5
    out = np.asarray(jax.jit(stacked)(*arrays[: np.sum(~zero)]))
    it = iter(arrays)
    expected = np.concatenate([np.zeros(batch) if z else next(it) for z in zero], axis=1)
    assert out.shape == (1, 400 * 5) and np.array_equal(out, expected)
