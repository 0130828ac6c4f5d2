"""The hierarchical sum's pair blocks (jaxsss.render.pairs.pair_blocks): the fewest blocks of at most ``block`` pairs,
split evenly, with little padding; and the near field split off a list (split_near)."""

import numpy as np
import pytest

from jaxsss.render.pairs import BLOCK_PAIRS, MIN_BLOCK, pair_blocks, split_near


@pytest.mark.parametrize("n", [0, 1, 255, 257, 40_000, 65_536, 65_537, 131_073, 1_000_003])
def test_blocks_hold_every_pair_once_in_the_fewest_blocks_with_little_padding(n):
    values = np.arange(n, dtype=np.int32)
    blocks = pair_blocks(values, -1, BLOCK_PAIRS)
    n_blocks, k = blocks.shape
    assert blocks.dtype == np.int32
    assert n_blocks == max(1, -(-n // BLOCK_PAIRS)) and k <= BLOCK_PAIRS and k % MIN_BLOCK == 0
    flat = blocks.reshape(-1)
    np.testing.assert_array_equal(flat[:n], values)
    assert np.all(flat[n:] == -1) and flat.size - n <= n_blocks * MIN_BLOCK


def test_padding_is_bounded_where_whole_blocks_wasted_half():
    """Just over one block: 3 blocks of 65536 (1.5x the work) before, now 3 blocks of 43776 (0.2% padding); a short
    list of 40,000 was padded to the next power of two (65536), now to 40,192."""
    assert pair_blocks(np.zeros(131_073, np.int32), 0, BLOCK_PAIRS).shape == (3, 43_776)
    assert pair_blocks(np.zeros(40_000, np.int32), 0, BLOCK_PAIRS).shape == (1, 40_192)


def test_a_block_smaller_than_the_rounding_is_kept():
    """A caller's tiny block (tests of the blocked sums use a few pairs) is a hard limit."""
    blocks = pair_blocks(np.arange(5), 9, 3)
    assert blocks.shape == (2, 3)
    np.testing.assert_array_equal(blocks.reshape(-1), [0, 1, 2, 3, 4, 9])


def test_split_near_takes_the_close_samples_and_keeps_the_order():
    """Near: sample pairs closer than the radius (nodes never, however close: counted apart); far: the rest. Both in
    the list's order, as int32."""
    from jaxsss.render.interactions import build_interactions
    from jaxsss.render.octree import build_octree

    rng = np.random.default_rng(2)
    p = rng.normal(size=(1500, 3))
    tree = build_octree(p, np.full(len(p), 0.01), np.ones(len(p)))
    x = rng.normal(size=(40, 3))
    inter = build_interactions(tree, x, 2.0)  # a large eps: nodes accepted close by too
    far_q, far_e, near_q, near_s, nodes_inside = split_near(inter, x, tree, 0.5)
    d2 = np.sum((tree.centroid[inter.entity] - x[inter.query]) ** 2, axis=1)
    close = d2 < 0.25
    near = close & (inter.entity < tree.n_samples)
    assert near.any() and (close & ~near).any()
    for got, want in ((far_q, inter.query[~near]), (far_e, inter.entity[~near]), (near_q, inter.query[near]),
                      (near_s, inter.entity[near])):
        assert got.dtype == np.int32
        np.testing.assert_array_equal(got, want)
    assert nodes_inside == np.count_nonzero(close & ~near)
