"""``jaxsss reparam``: agreement with an independent mpmath computation, round trips, output formats, user errors."""

import subprocess
import sys

import equinox as eqx
import jax
import jax.numpy as jnp
import mpmath as mp
import numpy as np
import optimistix as optx
import pytest

import jaxsss.reparam
from jaxsss.cli import main
from tests.cli.runner import run_cli, run_json


# --- Independent computation (mpmath, 50 digits) of the hierarchical paper's Eq. 15 and 16 --------------------------
mp.mp.dps = 50


def _A(eta):
    # Groenhuis et al. polynomial for eta >= 1 (the CLI's default --fresnel poly).
    eta = mp.mpf(eta)
    F_dr = -mp.mpf("1.4399") / eta**2 + mp.mpf("0.7099") / eta + mp.mpf("0.6681") + mp.mpf("0.0636") * eta
    return (1 + F_dr) / (1 - F_dr)


def _eq15(alpha, A):
    s = mp.sqrt(3 * (1 - alpha))
    return alpha / 2 * (1 + mp.exp(-mp.mpf(4) / 3 * A * s)) * mp.exp(-s)


def _alpha_from_rd(rd, A):
    """Bisection on Eq. 15 (increasing in alpha') to 2^-300: slow, obviously correct."""
    lo, hi = mp.mpf(0), mp.mpf(1)
    for _ in range(300):
        mid = (lo + hi) / 2
        lo, hi = (mid, hi) if _eq15(mid, A) < rd else (lo, mid)
    return (lo + hi) / 2


def independent_forward(rd, ld, eta, g):
    out = {k: [] for k in ("sigma_a", "sigma_s_prime", "alpha_prime", "rd", "ld", "eta", "sigma_s", "sigma_t")}
    A = _A(eta)
    for rd_c, ld_c in zip(rd, ld):
        alpha = _alpha_from_rd(mp.mpf(rd_c), A)
        sigma_tr = 1 / mp.mpf(ld_c)
        # Eq. 16: sigma_t' = sigma_tr / sqrt(3 (1 - alpha')).
        sigma_t_prime = sigma_tr / mp.sqrt(3 * (1 - alpha))
        sigma_s_prime = alpha * sigma_t_prime
        sigma_a = sigma_t_prime - sigma_s_prime
        sigma_s = sigma_s_prime / (1 - mp.mpf(g))
        values = dict(sigma_a=sigma_a, sigma_s_prime=sigma_s_prime, alpha_prime=alpha, rd=rd_c, ld=ld_c, eta=eta,
                      sigma_s=sigma_s, sigma_t=sigma_a + sigma_s)
        for k, v in values.items():
            out[k].append(float(v))
    return out


def independent_reverse(sigma_a, sigma_s_prime, eta):
    A = _A(eta)
    rd, ld = [], []
    for sa, ss in zip(sigma_a, sigma_s_prime):
        sa, ss = mp.mpf(sa), mp.mpf(ss)
        rd.append(float(_eq15(ss / (sa + ss), A)))
        ld.append(float(1 / mp.sqrt(3 * sa * (sa + ss))))
    return rd, ld


# The acceptance check: 1e-9 relative (the inversion itself is good to ~1e-14; 1e-9 is the contract).
ACCEPT_RTOL = 1e-9


@pytest.mark.parametrize("eta", [1.0, 1.3, 2.5])
def test_forward_matches_independent_computation_including_stiff_ends(capsys, eta):
    rd, ld, g = [1e-4, 0.3, 0.9999], [0.5, 2.0, 10.0], 0.7
    got = run_json(capsys, "reparam", "--rd", *rd, "--ld", *ld, "--eta", eta, "--g", g)
    want = independent_forward(rd, ld, eta, g)
    assert set(got) == set(want)
    for key in want:
        np.testing.assert_allclose(got[key], want[key], rtol=ACCEPT_RTOL, atol=0, err_msg=key)


def test_reverse_of_material_matches_independent_computation(capsys):
    got = run_json(capsys, "reparam", "--material", "Marble")
    want_rd, want_ld = independent_reverse([0.0021, 0.0041, 0.0071], [2.19, 2.62, 3.00], 1.5)
    np.testing.assert_allclose(got["rd"], want_rd, rtol=ACCEPT_RTOL)
    np.testing.assert_allclose(got["ld"], want_ld, rtol=ACCEPT_RTOL)
    assert got["eta"] == [1.5, 1.5, 1.5]  # the table's eta, broadcast per channel


@pytest.mark.parametrize("eta", [1.0, 2.5])
def test_round_trip_forward_then_reverse(capsys, eta):
    rd, ld = [1e-4, 0.5, 0.9999], [0.3, 1.0, 30.0]
    fwd = run_json(capsys, "reparam", "--rd", *rd, "--ld", *ld, "--eta", eta)
    rev = run_json(
        capsys, "reparam", "--sigma-a", *map(repr, fwd["sigma_a"]), "--sigma-s-prime", *map(repr, fwd["sigma_s_prime"]),
        "--eta", eta,
    )
    # Printing with repr is exact; the remaining error is the inversion's ~1e-13 and Eq. 15's conditioning.
    np.testing.assert_allclose(rev["rd"], rd, rtol=1e-10)
    np.testing.assert_allclose(rev["ld"], ld, rtol=1e-10)
    np.testing.assert_allclose(rev["alpha_prime"], fwd["alpha_prime"], rtol=1e-10)


def test_json_keys_exactly(capsys):
    base = ["reparam", "--rd", 0.5, 0.6, 0.7, "--ld", 1, 2, 3, "--eta", 1.3]
    keys = ["sigma_a", "sigma_s_prime", "alpha_prime", "rd", "ld", "eta"]
    assert list(run_json(capsys, *base)) == keys
    assert list(run_json(capsys, *base, "--g", 0.9)) == keys + ["sigma_s", "sigma_t"]
    assert list(run_json(capsys, "reparam", "--material", "skin1")) == keys


def test_single_value_broadcasts_to_the_other_options_channel_count(capsys):
    got = run_json(capsys, "reparam", "--rd", 0.5, "--ld", 1, 2, 3, "--eta", 1.3)
    assert got["rd"] == [0.5, 0.5, 0.5] and got["ld"] == [1.0, 2.0, 3.0]
    # sigma_a = sigma_tr u / 3 scales as 1 / l_d at fixed Rd.
    np.testing.assert_allclose(np.array(got["sigma_a"]) * got["ld"], got["sigma_a"][0], rtol=1e-13)
    one = run_json(capsys, "reparam", "--rd", 0.5, "--ld", 2, "--eta", 1.3)
    assert all(len(v) == 1 for v in one.values())
    five = run_json(capsys, "reparam", "--rd", 0.1, 0.2, 0.3, 0.4, 0.5, "--ld", 1, "--eta", 1.3)
    assert all(len(v) == 5 for v in five.values())


def test_spectralon_has_infinite_ld_printed_inf_and_null(capsys):
    got = run_json(capsys, "reparam", "--material", "spectralon")
    assert got["ld"] == [None, None, None]
    assert got["rd"] == [1.0, 1.0, 1.0] and got["sigma_a"] == [0.0, 0.0, 0.0]
    code, out, _ = run_cli(capsys, "reparam", "--material", "spectralon")
    assert code == 0
    ld_row = next(line for line in out.splitlines() if line.startswith("l_d"))
    assert ld_row.split()[-3:] == ["inf", "inf", "inf"]
    assert "nan" not in out.lower()


def test_table_is_aligned_with_channel_columns(capsys):
    code, out, err = run_cli(capsys, "reparam", "--rd", 0.5, 0.6, 0.7, "--ld", 1, 2, 3, "--eta", 1.3, "--g", 0.5)
    assert code == 0 and err == ""
    lines = out.splitlines()
    header = next(i for i, line in enumerate(lines) if line.startswith("quantity"))
    assert lines[header].split() == ["quantity", "unit", "R", "G", "B"]
    table = lines[header:]
    assert [line.split()[0] for line in table[1:]] == ["sigma_a", "sigma_s'", "alpha'", "Rd", "l_d", "eta", "sigma_s", "sigma_t"]
    assert len({len(line) for line in table}) == 1  # right-aligned numbers: every row ends in the same column
    code, out, _ = run_cli(capsys, "reparam", "--rd", 0.5, 0.6, "--ld", 1, "--eta", 1.3)
    assert next(line for line in out.splitlines() if line.startswith("quantity")).split() == ["quantity", "unit", "0", "1"]


def test_list_materials(capsys):
    from jaxsss.data import list_materials

    code, out, _ = run_cli(capsys, "reparam", "--list-materials")
    assert code == 0
    rows = [line.split() for line in out.splitlines()[1:]]
    assert [r[0] for r in rows] == list_materials()
    assert ["marble", "jensen2001", "1.5"] in rows
    assert ["espresso", "narasimhan2006", "-"] in rows


def test_narasimhan_material_with_eta(capsys):
    got = run_json(capsys, "reparam", "--material", "regular milk", "--eta", 1.33)
    assert got["eta"] == [1.33] * 3
    assert all(0 < x < 1 for x in got["rd"])


@pytest.mark.parametrize("fresnel", ["poly", "exact"])  # the NumPy path (jaxsss.reparam_np) and the library's
def test_non_converged_inversion_is_an_error_line(capsys, monkeypatch, fresnel):
    import jaxsss.reparam_np

    real = jaxsss.reparam.from_rd_ld
    real_np = jaxsss.reparam_np.from_rd_ld

    def failing(*args, **kwargs):
        rep = real(*args, **kwargs)
        # Pretend the green channel hit the iteration cap.
        cap = jax.vmap(lambda bad, res: optx.RESULTS.where(bad, optx.RESULTS.max_steps_reached, res))
        failed = cap(jnp.array([False, True, False]), rep.result)
        return eqx.tree_at(lambda r: r.result, rep, failed)

    def failing_np(*args, **kwargs):
        out = real_np(*args, **kwargs)
        out["converged"] = out["converged"] & np.array([True, False, True])
        return out

    monkeypatch.setattr(jaxsss.reparam, "from_rd_ld", failing)
    monkeypatch.setattr(jaxsss.reparam_np, "from_rd_ld", failing_np)
    code, out, err = run_cli(capsys, "reparam", "--rd", 0.5, 0.6, 0.7, "--ld", 1, "--eta", 1.3, "--json",
                             "--fresnel", fresnel)
    assert code == 2 and out == ""
    assert err.startswith("jaxsss: error:") and "did not converge" in err and err.count("\n") == 1
    assert "G (rd=0.6)" in err and "R (" not in err


USER_ERRORS = {
    "rd_above_one": (["--rd", 1.5, "--ld", 1, "--eta", 1.3], "rd=1.5"),
    "rd_zero": (["--rd", 0, "--ld", 1, "--eta", 1.3], "rd=0"),
    "rd_one": (["--rd", 1, "--ld", 1, "--eta", 1.3], "rd=1"),
    "ld_zero": (["--rd", 0.5, "--ld", 0, "--eta", 1.3], "ld=0"),
    "ld_negative": (["--rd", 0.5, "--ld", -2, "--eta", 1.3], "ld=-2"),
    "eta_zero": (["--rd", 0.5, "--ld", 1, "--eta", 0], "eta=0"),
    "eta_negative_reverse": (["--sigma-a", 0.1, "--sigma-s-prime", 1, "--eta", -1], "eta=-1"),
    "sigma_a_negative": (["--sigma-a", -0.1, "--sigma-s-prime", 1, "--eta", 1.3], "sigma_a=-0.1"),
    "sigma_s_prime_negative": (["--sigma-a", 0.1, "--sigma-s-prime", -1, "--eta", 1.3], "sigma_s_prime=-1"),
    "g_out_of_range": (["--rd", 0.5, "--ld", 1, "--eta", 1.3, "--g", 1], "g=1"),
    "unknown_material": (["--material", "unobtainium"], "unobtainium"),
    "malformed_number": (["--rd", "abc", "--ld", 1, "--eta", 1.3], "'abc'"),
    "nan_number": (["--rd", "nan", "--ld", 1, "--eta", 1.3], "'nan'"),
    "mismatched_channels": (["--rd", 0.5, 0.4, "--ld", 1, 2, 3, "--eta", 1.3], "channel counts"),
    "missing_ld": (["--rd", 0.5, "--eta", 1.3], "--ld"),
    "missing_eta": (["--rd", 0.5, "--ld", 1], "--eta"),
    "forward_and_reverse": (["--rd", 0.5, "--ld", 1, "--sigma-a", 0.1, "--eta", 1.3], "not both"),
    "nothing": ([], "nothing to convert"),
    "narasimhan_without_eta": (["--material", "espresso"], "--eta"),
    "unknown_fresnel": (["--rd", 0.5, "--ld", 1, "--eta", 1.3, "--fresnel", "magic"], "magic"),
}


@pytest.mark.parametrize("json_flag", [[], ["--json"]], ids=["table", "json"])
@pytest.mark.parametrize("argv, fragment", USER_ERRORS.values(), ids=USER_ERRORS.keys())
def test_user_errors_give_one_line_and_exit_2(capsys, argv, fragment, json_flag):
    code, out, err = run_cli(capsys, "reparam", *argv, *json_flag)
    assert code == 2
    assert out == ""
    assert err.startswith("jaxsss: error:") and err.count("\n") == 1, err
    assert fragment in err


@pytest.mark.parametrize("command", ["reparam", "profile", "run"])
def test_help_states_units(capsys, command):
    with pytest.raises(SystemExit) as exc:
        main([command, "--help"])
    assert exc.value.code == 0
    text = " ".join(capsys.readouterr().out.split())
    for unit in ("1/mm", "mm", "eta = n_inside / n_outside"):
        assert unit in text


def test_module_entry_point_exits_2_without_traceback():
    proc = subprocess.run(
        [sys.executable, "-m", "jaxsss", "reparam", "--rd", "0.5", "--ld", "-1", "--eta", "1.3"],
        capture_output=True, text=True, timeout=120,
    )
    assert proc.returncode == 2
    assert proc.stdout == ""
    assert proc.stderr.startswith("jaxsss: error:") and proc.stderr.count("\n") == 1, proc.stderr
    assert "Traceback" not in proc.stderr
