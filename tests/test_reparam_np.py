"""jaxsss.reparam_np (the NumPy path of `jaxsss reparam`) against the library's from_rd_ld (JAX)."""

import subprocess
import sys

import numpy as np
import pytest

import jaxsss
from jaxsss import reparam_np
from jaxsss.cli._common import FRESNEL_METHODS


def test_agrees_with_the_library_over_the_range():
    """Rd from 1e-9 to 1 - 1e-9 (both stiff ends), eta on both sides of 1 and at 1, with g: 1e-12 relative."""
    rd = np.concatenate([np.geomspace(1e-9, 0.5, 25), 1.0 - np.geomspace(0.5, 1e-9, 25)[1:]])
    for eta in (0.5, 1.0, 1.0001, 1.3, 2.5):
        ld = np.geomspace(1e-3, 1e3, rd.size)
        want = jaxsss.from_rd_ld(rd, ld, eta, 0.9)
        got = reparam_np.from_rd_ld(rd, ld, eta, 0.9)
        assert got["converged"].all() and np.asarray(want.converged).all()
        # 1e-12: the same closed forms and Newton iteration (tolerance 1e-13 on s) in NumPy instead of XLA.
        for key, ref in (("sigma_a", want.medium.sigma_a), ("sigma_s_prime", want.medium.sigma_s_prime),
                         ("alpha_prime", want.alpha_prime), ("sigma_s", want.medium.sigma_s),
                         ("sigma_t", want.medium.sigma_t)):
            np.testing.assert_allclose(got[key], np.asarray(ref), rtol=1e-12, err_msg=f"{key}, eta {eta}")
    np.testing.assert_allclose(reparam_np.A_poly([0.5, 1.0, 1.3, 2.5]),
                               np.asarray(jaxsss.A_coefficient(np.array([0.5, 1.0, 1.3, 2.5]), "poly")), rtol=1e-14)


@pytest.mark.parametrize("kwargs, match", [
    ({"rd": 1.0, "ld": 1.0, "eta": 1.3}, "rd=1"), ({"rd": 0.5, "ld": 0.0, "eta": 1.3}, "ld=0"),
    ({"rd": 0.5, "ld": 1.0, "eta": -1.0}, "eta=-1"), ({"rd": np.nan, "ld": 1.0, "eta": 1.3}, "rd=nan"),
    ({"rd": 0.5, "ld": 1.0, "eta": 1.3, "g": 1.0}, "g=1"),
])
def test_bad_input_names_the_argument(kwargs, match):
    with pytest.raises(ValueError, match=match):
        reparam_np.from_rd_ld(**kwargs)


def test_fresnel_names_match_the_library():
    assert set(FRESNEL_METHODS) == set(jaxsss.F_DR_METHODS)


def test_one_value_process_imports_no_jax():
    """`jaxsss reparam` of one value (the default F_dr) runs without importing JAX (start-up, issue 18)."""
    code = ("import sys; from jaxsss.cli import main; main(['reparam', '--rd', '0.5', '--ld', '1', '--eta', '1.3']); "
            "print('jax' in sys.modules)")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip().splitlines()[-1] == "False"
    assert "sigma_a" in proc.stdout
