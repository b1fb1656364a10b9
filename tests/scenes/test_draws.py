"""Named random draws (jaxsr.scenes.draws): a draw's numbers depend only on the key, its path and its shape."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxsr.scenes import layouts
from jaxsr.scenes.draws import Draws, with_draws
from jaxsr.scenes.objects import many


def build_ab(d: Draws, *, more=False):
    extra = d.uniform("extra", shape=(7,)) if more else None  # new draws, taken first
    obj = d.child("obj")
    c = obj.uniform("c") if more else None
    return {"a": d.uniform("a", shape=(3,)), "b": obj.uniform("b", 2.0, 4.0), "extra": (extra, c)}


def test_a_new_draw_leaves_the_others_unchanged():
    key = jax.random.key(11)
    one = jax.jit(lambda k: with_draws(build_ab, k))(key)  # both jitted: the same float rounding
    two = jax.jit(lambda k: with_draws(lambda d: build_ab(d, more=True), k))(key)
    np.testing.assert_array_equal(one["a"], two["a"])
    np.testing.assert_array_equal(one["b"], two["b"])
    other = with_draws(build_ab, jax.random.key(12))
    assert not np.allclose(one["a"], other["a"])


def test_ranges_and_distributions():
    def build(d):
        return d.uniform("u", -2.0, 3.0, (20000,)), d.coin("c", 0.3, (20000,)), d.child("n").count("k", 2, 5)

    u, c, k = with_draws(build, jax.random.key(0))
    u, c = np.asarray(u), np.asarray(c)
    assert u.min() >= -2.0 and u.max() < 3.0
    # 20000 draws: the mean's standard error is 0.01 for u (sd 1.44) and 0.003 for the coin.
    assert abs(u.mean() - 0.5) < 0.05 and abs(c.mean() - 0.3) < 0.015
    ks = [int(with_draws(lambda d: d.count("k", 2, 5), jax.random.key(i))) for i in range(200)]
    assert set(ks) == {2, 3, 4, 5}
    # Different names are independent: their correlation is at noise level.
    a, b = with_draws(lambda d: (d.uniform("x", shape=(20000,)), d.uniform("y", shape=(20000,))), jax.random.key(1))
    assert abs(np.corrcoef(a, b)[0, 1]) < 0.03


def test_vmapped_objects_get_their_own_numbers():
    def obj(d, base):
        return d.uniform("size", 1.0, 2.0) + 0.0 * base

    def build(d):
        return many(lambda dd, b: {"size": obj(dd, b)}, d, "things", 4, jnp.arange(4.0)), d.uniform("alone")

    things, alone = with_draws(build, jax.random.key(3))
    sizes = np.asarray(things["size"])
    assert sizes.shape == (4,) and len(set(sizes.tolist())) == 4 and np.all((sizes >= 1) & (sizes < 2))
    # The same objects built without the unrelated draw: identical.
    again = with_draws(lambda d: many(lambda dd, b: {"size": obj(dd, b)}, d, "things", 4, jnp.arange(4.0)),
                       jax.random.key(3))
    np.testing.assert_array_equal(sizes, np.asarray(again["size"]))


def test_a_name_taken_twice_is_an_error():
    with pytest.raises(ValueError, match="taken twice"):
        with_draws(lambda d: d.uniform("x") + d.uniform("x"), jax.random.key(0))
    with pytest.raises(ValueError, match="taken twice"):
        with_draws(lambda d: (d.child("p"), d.child("p")), jax.random.key(0))
    with pytest.raises(ValueError, match="must not contain"):
        with_draws(lambda d: d.uniform("a/b"), jax.random.key(0))


def test_sampler_scenes_survive_a_new_draw_in_a_layout(monkeypatch):
    """The property the test scenes lacked: an extra draw in one layout changes nothing else in the scene."""
    key, options = jax.random.key(21), (("n_people", (3, 5)),)
    sample = jax.jit(layouts._sample_scene_jit.__wrapped__, static_argnums=(1, 2, 3))  # a fresh trace each call
    before = sample(key, "street", "random", options)
    street = layouts._KIND_FNS["street"]

    def street_with_an_extra_draw(d, **options):
        d.uniform("a_new_quantity", shape=(5,))
        return street(d, **options)

    monkeypatch.setitem(layouts._KIND_FNS, "street", street_with_an_extra_draw)
    after = jax.jit(layouts._sample_scene_jit.__wrapped__, static_argnums=(1, 2, 3))(key, "street", "random", options)
    for a, b in zip(jax.tree.leaves(before), jax.tree.leaves(after)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
