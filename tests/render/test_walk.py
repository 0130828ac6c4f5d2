"""The renderer's offline transport walks (:mod:`jaxsss.render.walk`): the diffuse-light walk with a Fresnel boundary
against Chandrasekhar and adding-doubling, and its sphere's gain."""

import iadpython
import jax.numpy as jnp
import numpy as np
import pytest

from jaxsss.fresnel import fresnel_unpolarised
from jaxsss.render.anisotropic_albedo import dielectric_directional_albedo
from jaxsss.render.bssrdf import directional_albedo
from jaxsss.render.walk import diffuse_light_walk, pencil_beam_walk

PHOTONS = 40_000


def _hemispherical(f):
    """``2 int_0^1 f(mu) mu dmu`` (cosine-weighted hemisphere), 200-point Gauss-Legendre."""
    t, w = np.polynomial.legendre.leggauss(200)
    mu = 0.5 * (t + 1.0)
    return float(np.sum(w * mu * f(mu)))


def test_the_index_matched_half_space_is_chandrasekhars():
    """At ``eta = 1`` the half-space returns ``2 int A(mu) mu dmu`` of diffuse light (Chandrasekhar's exact directional
    albedo) within three standard errors (about 1% at 4e4 photons)."""
    albedo = 0.75
    exact = _hemispherical(lambda mu: np.asarray(directional_albedo(jnp.asarray(mu), albedo)))
    walk = diffuse_light_walk(albedo, 1.0, PHOTONS, 3)
    np.testing.assert_allclose(walk, exact, rtol=0.012)


def test_a_dielectric_half_space_against_adding_doubling():
    """At ``eta = 1.33`` against adding-doubling (iadpython, semi-infinite, 16 points): its diffuse reflectance
    ``URU`` less the surface's own specular reflection of diffuse light, ``2 int F(mu) mu dmu``."""
    albedo, eta = 0.9, 1.33
    uru = float(iadpython.Sample(a=albedo, b=1e4, g=0.0, n=eta, quad_pts=16).rt()[2])
    specular = _hemispherical(lambda mu: fresnel_unpolarised(mu, eta, xp=np))
    walk = diffuse_light_walk(albedo, eta, PHOTONS, 4)
    np.testing.assert_allclose(walk, uru - specular, rtol=0.015)


def test_a_sphere_returns_more_and_a_dielectric_sphere_more_still():
    """Transport's curvature gain for diffuse light (sphere over half-space) exceeds 1, falls with the radius, and is
    larger under a dielectric boundary (internal reflection keeps the light in until it finds a way out): at albedo
    0.75 and 4.8 mean free paths about 1.28 index-matched and 1.45 at ``eta = 1.33`` (docs/path_tracer.md)."""
    albedo = 0.75
    gain = {}
    for eta in (1.0, 1.33):
        plane = diffuse_light_walk(albedo, eta, PHOTONS, 5)
        gain[eta] = [diffuse_light_walk(albedo, eta, PHOTONS, 6 + k, radius=a) / plane
                     for k, a in enumerate((4.8, 11.1))]
    assert 1.0 < gain[1.0][1] < gain[1.0][0] and 1.0 < gain[1.33][1] < gain[1.33][0], gain
    assert gain[1.33][0] > gain[1.0][0] + 0.1, gain
    np.testing.assert_allclose([gain[1.0][0], gain[1.33][0]], [1.28, 1.45], rtol=0.04)


def test_bad_input_is_named():
    with pytest.raises(ValueError, match=r"diffuse_light_walk\(albedo=1.0\)"):
        diffuse_light_walk(1.0, 1.0, 10, 0)
    with pytest.raises(ValueError, match=r"diffuse_light_walk\(eta=0.0\)"):
        diffuse_light_walk(0.5, 0.0, 10, 0)
    with pytest.raises(ValueError, match=r"diffuse_light_walk\(radius=-1.0\)"):
        diffuse_light_walk(0.5, 1.0, 10, 0, radius=-1.0)


@pytest.mark.parametrize("eta", [1.33, 1.5])
def test_a_pencil_beam_behind_a_boundary_reflects_adding_doublings_albedo(eta):
    """The Fresnel pencil beam on the half-space (:func:`pencil_beam_walk` with ``eta``: Snell and the entry's
    transmittance, Fresnel at every crossing) sends back the dielectric directional albedo of adding-doubling
    (:func:`jaxsss.render.anisotropic_albedo.dielectric_directional_albedo`, a separate method) at incidence cosines 1,
    0.5 and 0.1 within 1.5% (30000 photons: 0.5% noise)."""
    albedo = 0.95
    exact = np.asarray(dielectric_directional_albedo(np.array([1.0, 0.5, 0.1]), jnp.array([albedo]), 0.0, eta))[:, 0]
    for k, mu in enumerate((1.0, 0.5, 0.1)):
        total = [0.0]

        def tally(first, exit_point, direction, weight, total=total):
            total[0] += float(np.sum(weight))

        pencil_beam_walk(albedo, mu, 30_000, 17 + k, tally, eta=eta)
        assert total[0] / 30_000 == pytest.approx(exact[k], rel=1.5e-2), (mu, total[0] / 30_000, exact[k])


def test_a_node_added_later_leaves_the_shipped_rows_and_gets_its_own_seeds():
    """A table's walks draw each node's seeds from its slot in ``SEED_ORDER`` among the table's nodes: the rows of a
    node do not depend on which other nodes are walked with it, so ``--add-node`` (``insert_node``) builds the same
    table as walking every node at once (the cut beam's table, 3000 photons per node)."""
    from jaxsss.render.passage import PASSAGE_MUS, generate_passage_table
    from jaxsss.render.walk import SEED_ORDER, insert_node, seed_slot

    assert [seed_slot(m, PASSAGE_MUS) for m in (1.0, 0.5, 0.1, 0.75)] == [0, 1, 2, 3]
    assert [seed_slot(m, (0.75, 0.5, 0.1)) for m in (0.5, 0.1, 0.75)] == [0, 1, 2]  # a table without the normal node
    assert set(PASSAGE_MUS) <= set(SEED_ORDER)
    whole = generate_passage_table(3000, progress=False, mus=(1.0, 0.75, 0.5))
    older = generate_passage_table(3000, progress=False, mus=(1.0, 0.5))
    part = generate_passage_table(3000, progress=False, mus=(0.75,))
    added = insert_node(older, part, ("loss",))
    np.testing.assert_array_equal(added["mus"], whole["mus"])
    np.testing.assert_array_equal(added["loss"], whole["loss"])
    assert added["seconds"] == pytest.approx(older["seconds"] + part["seconds"])
    with pytest.raises(ValueError, match="lacks"):
        insert_node(whole, part, ("loss",))
    with pytest.raises(ValueError, match="SEED_ORDER"):
        seed_slot(0.3, PASSAGE_MUS)


def test_an_albedo_added_later_leaves_the_shipped_rows_and_gets_its_own_seeds():
    """``--add-albedo`` (``insert_albedo``): an albedo's walks draw their seeds from its index among the whole table's
    albedos (``table_albedo``), so walking it alone and appending its rows builds the same table as walking every albedo
    at once (a tally that records its arguments; the real walks are these calls). A new albedo must exceed the last
    and come with the table's incidence nodes."""
    from jaxsss.render.walk import insert_albedo, sphere_and_plane_tallies

    def tally(albedo, mu, radius, photons, seed):
        return np.array([albedo, mu, -1.0 if radius is None else radius, float(seed)])

    args = (tally, (1.0, 0.5), None, (2.0, 3.0), 10, 47, "test", False)
    albedos = (0.3, 0.9, 0.999)

    def table(part_albedos, table_albedo):
        sphere, plane = sphere_and_plane_tallies(*args[:2], part_albedos, *args[3:], table_albedo=table_albedo)
        return {"sphere": sphere, "plane": plane, "mus": np.array([1.0, 0.5]), "albedo": np.array(part_albedos),
                "seconds": 1.0}

    whole = table(albedos, None)
    added = insert_albedo(table(albedos[:2], albedos), table(albedos[2:], albedos), ("sphere", "plane"))
    for key in ("albedo", "sphere", "plane"):
        np.testing.assert_array_equal(added[key], whole[key])
    # Without the whole table's albedos the new one would take the first albedo's seeds.
    alone = table(albedos[2:], None)
    assert alone["plane"][0, 0, 3] == whole["plane"][0, 0, 3] != whole["plane"][0, 2, 3]
    assert added["seconds"] == 2.0
    with pytest.raises(ValueError, match="above the table's last"):
        insert_albedo(whole, table((0.95,), None), ("plane",))
    with pytest.raises(ValueError, match="mus"):
        insert_albedo(table(albedos[:2], albedos), {**table(albedos[2:], albedos), "mus": np.array([1.0])}, ("plane",))
    with pytest.raises(ValueError, match="no seed slot"):
        table((0.9999,), albedos)
