"""Photons split over devices (``simulate(devices=...)``): 2 forced host CPU devices against 1 device.

JAX fixes its number of CPU devices when its backend starts, so the sharded run happens in a fresh interpreter with
``JAX_NUM_CPU_DEVICES=2``; it prints both results as JSON and the checks run here.
"""

import json
import os
import subprocess
import sys
from pathlib import Path

import jax
import pytest

from jaxsss.mc import Stack, simulate
from jaxsss.mc.engine import use_cpu_devices

ROOT = Path(__file__).resolve().parents[2]
PHOTONS = 20_001  # odd: the devices' shares differ by one photon

CHILD = f"""
import json, jax
from jaxsss.mc import Stack, simulate
jax.config.update("jax_numpy_dtype_promotion", "strict")  # as in tests/conftest.py
assert len(jax.devices()) == 2, jax.devices()
stack = Stack.slab(0.1, 0.9, 0.75, 1.4, 1.0)
out = {{}}
for name, kw in (("one", dict(devices=1)), ("two", dict(devices=2)), ("two_again", dict(devices=None)),
                 ("two_seed", dict(devices=2, seed=8))):
    kw.setdefault("seed", 7)
    r = simulate(stack, {PHOTONS}, progress=False, **kw)
    out[name] = dict(devices=r.devices, photons=r.photons, R=r.R_diffuse, R_se=r.R_diffuse_stderr, T=r.T,
                     T_se=r.T_stderr, A=r.A, A_se=r.A_stderr, balance=r.weight_balance, lanes=r.lanes,
                     occupancy=r.lane_occupancy)
print(json.dumps(out))
"""


@pytest.fixture(scope="module")
def runs():
    path = str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", "")
    env = dict(os.environ, JAX_NUM_CPU_DEVICES="2", PYTHONPATH=path)
    proc = subprocess.run([sys.executable, "-c", CHILD], env=env, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return json.loads(proc.stdout.strip().splitlines()[-1])


def test_two_devices_agree_with_one_within_standard_errors(runs):
    one, two = runs["one"], runs["two"]
    assert one["devices"] == 1 and two["devices"] == 2
    for k in ("R", "T", "A"):
        se = (one[k + "_se"] ** 2 + two[k + "_se"] ** 2) ** 0.5
        assert abs(one[k] - two[k]) < 4 * se, (k, one[k], two[k], se)
    # Different streams (device d folds d into the batch key), so not bit-identical to one device.
    assert one["R"] != two["R"]


def test_every_photon_is_run_exactly_once_across_devices(runs):
    # Weight bookkeeping closes only if the shares add up to exactly PHOTONS launched photons.
    for r in runs.values():
        assert r["photons"] == PHOTONS
        assert abs(r["balance"] - 1.0) < 1e-12
        assert 0.3 < r["occupancy"] <= 1.0  # events / (iterations x lanes), iterations summed over devices


def test_reproducible_for_a_given_device_count(runs):
    assert runs["two_again"] == runs["two"]  # devices=None takes all (2) devices: the same program and streams
    assert runs["two_seed"]["R"] != runs["two"]["R"]


def test_device_count_is_validated():
    stack = Stack.half_space(0.1, 1.0, 0.0, 1.0)
    have = len(jax.devices())
    with pytest.raises(ValueError, match=rf"devices=0.*allowed range \[1, {have}\]"):
        simulate(stack, 10, devices=0)
    with pytest.raises(ValueError, match=rf"devices={have + 1}.*JAX_NUM_CPU_DEVICES"):
        simulate(stack, 10, devices=have + 1)
    with pytest.raises(ValueError, match=r"n=0.*\[1, inf\)"):
        use_cpu_devices(0)
    simulate(stack, 10, devices=1)  # the backend runs now: asking for another count is refused, the same is not
    cpus = len(jax.devices("cpu"))
    with pytest.raises(ValueError, match=f"already runs with {cpus} CPU device"):
        use_cpu_devices(cpus + 1)
    assert use_cpu_devices(cpus) == cpus
