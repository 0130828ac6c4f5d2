"""Reading MCML 1.2.2's ASCII output (``.mco``, file format ``A1``; Wang, Jacques and Zheng 1995).

An ``.mco`` file holds the run's input (``InParm``: photon count, grid, layers, ambient indices) and its results:
``RAT`` (specular reflectance, diffuse reflectance ``Rd``, absorbed fraction ``A``, total transmittance ``Tt``), the
1-D arrays ``A_l``, ``A_z``, ``Rd_r``, ``Rd_a``, ``Tt_r``, ``Tt_a`` and the 2-D arrays ``A_rz``, ``Rd_ra``,
``Tt_ra``. MCML writes lengths in cm and coefficients in 1/cm; :func:`read_mco` converts them to the project's units:

=====================  ====================  =====================
quantity               in the file           in :class:`McoRun`
=====================  ====================  =====================
``dz``, ``dr``,        cm                    mm (x 10)
thicknesses
``mua``, ``mus``       1/cm                  1/mm (x 0.1)
``Rd_r``, ``Tt_r``     1/cm^2                1/mm^2 (x 0.01)
``A_z``                1/cm                  1/mm (x 0.1)
``A_rz``               1/cm^3                1/mm^3 (x 0.001)
``Rd_ra``, ``Tt_ra``   1/(cm^2 sr)           1/(mm^2 sr) (x 0.01)
=====================  ====================  =====================

Radial bins. MCML's bin ``i`` (``0 <= i < nr``) is the annulus ``[i dr, (i + 1) dr)``, and ``Rd_r[i]`` is the
weight that left through it per incident photon divided by the annulus area ``pi dr^2 (2 i + 1)``: an annulus
average, per incident photon (MCML's ``Rd`` excludes the specular reflection; ``Tt`` includes the unscattered beam,
which lands in bin 0). MCML collects every photon beyond the grid in the *last* bin, so ``Rd_r[nr - 1]`` is not a
profile value: :meth:`McoRun.to_profile` drops it. :class:`McoRun` keeps all ``nr`` bins with their edges
``r_lo``, ``r_hi``; the :class:`~fitting.io.ProfileData` it returns puts each value at its bin *centre*
``(i + 1/2) dr`` (the CSV convention of :mod:`fitting.io`: one radius per value, in mm).

Standard errors. MCML does not write them (nor the photon counts per bin). :func:`bin_standard_errors` uses the
photon count ``N``: a photon leaves through bin ``i`` at most once, with a weight ``w <= 1`` (absorption and Russian
roulette only lower it: a roulette survivor below 1e-4 is multiplied by 10), so the per-photon contribution
``X = w 1[bin i]`` has ``Var X = E[w^2 1] - p^2 <= p (1 - p)`` with ``p = E[X] = Rd_r[i] * area_i``. Hence
``SE_i <= sqrt(p (1 - p) / N) / area_i`` -- exact without absorption (every weight 1), an upper bound with it. A bin
that caught no photon (``p = 0``) would get ``SE = 0``; there ``p`` is replaced by ``1/N`` (the value one photon of
full weight would give), so the bin is weighted like a one-photon count and never gets an infinite weight.
Bins with few photons (far from the source) are therefore noisy *and* weighted as such; a fit's default radial
range already stops where the data fade (see :func:`fitting.fit_profile`).

A malformed file raises :class:`~fitting.io.ProfileFileError` naming the file and the line: an unknown format
version, a token that is not a number, a missing or truncated block, a unit other than MCML's, or a value outside
its range.
"""

from __future__ import annotations

import math
import re
from pathlib import Path
from typing import NamedTuple

import numpy as np

from fitting.io import ProfileData, ProfileFileError

__all__ = ["McoLayer", "McoRun", "SEMI_INFINITE_MM", "bin_standard_errors", "poisson_stderr", "read_mco"]

SEMI_INFINITE_MM = 1e6
"""A layer at least this thick (1 km; MCML users write ``1E+08`` cm) counts as semi-infinite."""

_CM = 10.0  # mm per cm
# The blocks of an A1 file, in order, with the unit MCML writes in the block's title comment (None: no unit there).
_BLOCKS = ("InParm", "RAT", "A_l", "A_z", "Rd_r", "Rd_a", "Tt_r", "Tt_a", "A_rz", "Rd_ra", "Tt_ra")
_UNITS = {"A_l": "[-]", "A_z": "[1/cm]", "Rd_r": "[1/cm2]", "Rd_a": "[sr-1]", "Tt_r": "[1/cm2]", "Tt_a": "[sr-1]"}
# Units written on the comment lines just above the 2-D blocks (MCML puts them there, not on the title line).
_UNITS_ABOVE = {"A_rz": "[1/cm3]", "Rd_ra": "[1/(cm2sr)]", "Tt_ra": "[1/(cm2sr)]"}
_SCALE = {"RAT": 1.0, "A_l": 1.0, "A_z": 1 / _CM, "Rd_r": 1 / _CM**2, "Rd_a": 1.0, "Tt_r": 1 / _CM**2, "Tt_a": 1.0,
          "A_rz": 1 / _CM**3, "Rd_ra": 1 / _CM**2, "Tt_ra": 1 / _CM**2}
# A bracketed unit: ``[-]`` or one naming a length or solid angle (``[A[0][1]`` index comments are not units).
_UNIT_RE = re.compile(r"\[(?:-|[^\]\[]*(?:cm|mm|sr|m)[^\]\[]*)\]")


class McoLayer(NamedTuple):
    """One MCML layer in mm and 1/mm: refractive index ``n``, absorption ``mua``, scattering ``mus`` (not reduced),
    Henyey-Greenstein ``g`` and ``thickness`` (mm; :attr:`semi_infinite` when at least :data:`SEMI_INFINITE_MM`)."""

    n: float
    mua: float
    mus: float
    g: float
    thickness: float

    @property
    def sigma_a(self) -> float:
        """``mua`` (1/mm), the project's name."""
        return self.mua

    @property
    def sigma_s_prime(self) -> float:
        """Reduced scattering ``mus (1 - g)`` (1/mm)."""
        return self.mus * (1.0 - self.g)

    @property
    def semi_infinite(self) -> bool:
        """The layer is thick enough to stand for a half-space (MCML has no infinite layers)."""
        return self.thickness >= SEMI_INFINITE_MM


class McoRun(NamedTuple):
    """An MCML run read by :func:`read_mco`, in mm and 1/mm (conversions in the module docstring).

    Attributes:
        source: the file's path.
        photons: number of photons launched ``N``.
        seconds: the run's user time (the ``# User time`` line), or ``nan`` if absent.
        dz, dr: grid steps (mm); nz, nr, na: grid sizes (depth, radius, exit angle).
        layers: the layers top to bottom (:class:`McoLayer`).
        n_above, n_below: refractive indices of the ambient media above and below.
        specular, Rd, A, Tt: the totals per incident photon (``Rd`` without the specular reflection; ``Tt`` with the
            unscattered beam).
        r_lo, r_hi: edges of the ``nr`` radial bins (mm); the last bin also holds every photon beyond ``nr dr``.
        Rd_r, Tt_r: radial reflectance and transmittance, 1/mm^2 per incident photon (annulus averages), shape
            ``(nr,)``.
        A_l: absorbed fraction per layer, shape ``(n_layers,)``; A_z: absorption per unit depth (1/mm), ``(nz,)``.
        Rd_a, Tt_a: per exit angle (1/sr), ``(na,)``; A_rz (1/mm^3), Rd_ra, Tt_ra (1/(mm^2 sr)): 2-D arrays.
    """

    source: str
    photons: int
    seconds: float
    dz: float
    dr: float
    nz: int
    nr: int
    na: int
    layers: tuple
    n_above: float
    n_below: float
    specular: float
    Rd: float
    A: float
    Tt: float
    r_lo: np.ndarray
    r_hi: np.ndarray
    Rd_r: np.ndarray
    Tt_r: np.ndarray
    A_l: np.ndarray
    A_z: np.ndarray
    Rd_a: np.ndarray
    Tt_a: np.ndarray
    A_rz: np.ndarray
    Rd_ra: np.ndarray
    Tt_ra: np.ndarray

    @property
    def r_centre(self) -> np.ndarray:
        """Bin centres ``(i + 1/2) dr`` (mm), shape ``(nr,)``."""
        return 0.5 * (self.r_lo + self.r_hi)

    @property
    def semi_infinite(self) -> bool:
        """The deepest layer stands for a half-space (no transmission profile to fit)."""
        return self.layers[-1].semi_infinite

    @property
    def thickness(self) -> float:
        """Total thickness of the stack (mm); ``inf`` when the deepest layer is semi-infinite."""
        return math.inf if self.semi_infinite else float(sum(layer.thickness for layer in self.layers))

    @property
    def eta(self) -> float:
        """``n_top_layer / n_above``: the relative index at the illuminated face (the project's ``eta``)."""
        return self.layers[0].n / self.n_above

    def to_profile(self) -> ProfileData:
        """The profiles as :class:`~fitting.io.ProfileData`: radii at the bin centres (mm), ``R`` = ``Rd_r`` and,
        for a finite stack, ``T`` = ``Tt_r`` (1/mm^2 per incident photon), with :func:`bin_standard_errors`. The last
        (overflow) bin is dropped; ``T`` keeps the unscattered beam in its first bin, as MCML writes it."""
        keep = slice(0, self.nr - 1)
        r = self.r_centre[keep]
        R, R_se = self.Rd_r[keep], bin_standard_errors(self, self.Rd_r)[keep]
        T = T_se = None
        if not self.semi_infinite:
            T, T_se = self.Tt_r[keep], bin_standard_errors(self, self.Tt_r)[keep]
        return ProfileData(r=r, R=R, R_stderr=R_se, T=T, T_stderr=T_se, source=self.source,
                           r_edges=np.append(self.r_lo[keep], self.r_hi[self.nr - 2]))


def poisson_stderr(value, photons: int, area=1.0, *, empty_as_one: bool = False):
    """Poisson-like standard error of a Monte Carlo tally: ``sqrt(p (1 - p) / N) / area`` with ``p = value * area``
    (the fraction of the ``N`` incident photons in the bin). Exact for unit-weight photons; photons whose weight was
    reduced by absorption make the true error smaller, so it is conservative. ``empty_as_one``: a bin that caught no
    photon gets one photon's error (``p`` replaced by ``1/N`` in the first factor) instead of zero."""
    p = np.clip(np.asarray(value, dtype=np.float64) * area, 0.0, 1.0)
    q = np.maximum(p, 1.0 / photons) if empty_as_one else p
    return np.sqrt(q * (1.0 - p) / photons) / area


def bin_standard_errors(run: McoRun, values) -> np.ndarray:
    """Standard errors (same unit as ``values``, 1/mm^2) of a radial array of ``run`` (``Rd_r`` or ``Tt_r``), from the
    photon count: :func:`poisson_stderr` over each annulus with an empty bin counted as one photon, i.e.
    ``sqrt(max(p, 1/N) (1 - p) / N) / area`` (an upper bound; exact without absorption -- see the module
    docstring)."""
    area = np.pi * (run.r_hi**2 - run.r_lo**2)
    return poisson_stderr(values, run.photons, area, empty_as_one=True)


# --- Parsing ------------------------------------------------------------------------------------------------------
class _Line(NamedTuple):
    no: int
    tokens: list
    comment: str


def _lines(text: str):
    """Every line (``lines[i].no == i + 1``) with the tokens before ``#`` and the comment after it."""
    out = []
    for no, raw in enumerate(text.splitlines(), start=1):
        body, _, comment = raw.partition("#")
        out.append(_Line(no, body.split(), comment))
    return out


def _number(token: str, path, no: int, what: str) -> float:
    try:
        value = float(token)
    except ValueError:
        raise ProfileFileError(f"{path}: line {no}: {token!r} is not a number ({what})") from None
    if not math.isfinite(value):
        raise ProfileFileError(f"{path}: line {no}: {token!r} is not a finite number ({what})")
    return value


def _check(ok: bool, path, no: int, message: str) -> None:
    if not ok:
        raise ProfileFileError(f"{path}: line {no}: {message}")


def _split_blocks(lines, path):
    """``{block: (title line, [(line no, token), ...])}``: every token after a block's title belongs to it."""
    blocks, current, order = {}, None, []
    for line in lines:
        for token in line.tokens:
            if token in _BLOCKS:
                _check(token not in blocks, path, line.no, f"block {token} appears twice")
                current = token
                blocks[token] = (line, [])
                order.append(token)
                continue
            if current is None:
                if token == "A1":
                    continue
                raise ProfileFileError(f"{path}: line {line.no}: expected the format version A1 and then the block "
                                       f"InParm; found {token!r} (is this an MCML 1.2.2 .mco file?)")
            blocks[current][1].append((line.no, token))
    if order != [b for b in _BLOCKS if b in order]:
        raise ProfileFileError(f"{path}: line {blocks[order[0]][0].no}: blocks out of order: {', '.join(order)}; "
                               f"MCML writes {', '.join(_BLOCKS)}")
    return blocks


def _block(blocks, name, lines, path):
    """``blocks[name]``, or an error naming the line after which it was expected (blocks are read in file order, so
    a file cut inside a block reports that block as short before the blocks after it as missing)."""
    if name not in blocks:
        last_no = lines[-1].no if lines else 0
        after = [b for b in _BLOCKS[: _BLOCKS.index(name)] if b in blocks]
        where = blocks[after[-1]][1][-1][0] if after and blocks[after[-1]][1] else last_no
        raise ProfileFileError(f"{path}: line {where}: missing block {name} (expected after "
                               f"{after[-1] if after else 'the version line'}); the file is truncated or not "
                               "an MCML 1.2.2 .mco file")
    return blocks[name]


def _take(tokens, count, path, block, title_no, what):
    """The first ``count`` numbers of a block's tokens (as floats) and the rest; a short block is truncation."""
    if len(tokens) < count:
        no = tokens[-1][0] if tokens else title_no
        raise ProfileFileError(f"{path}: line {no}: block {block} ends after {len(tokens)} of {count} values "
                               f"({what}); the file is truncated")
    values = np.array([_number(tok, path, no, f"{block}, {what}") for no, tok in tokens[:count]])
    return values, tokens[count:]


def _check_unit(line: _Line, expected: str, path, block: str) -> None:
    found = _UNIT_RE.findall(line.comment)
    if found and found[-1].replace(" ", "") != expected:
        raise ProfileFileError(f"{path}: line {line.no}: block {block} is in {found[-1]}; MCML 1.2.2 writes "
                               f"{expected} (this reader converts from MCML's units)")


def _parse_inparm(tokens, title: _Line, lines, path):
    """The ``InParm`` block: output name and format, photons, dz dr, nz nr na, layers, ambient indices."""
    _check("cm" in title.comment or not title.comment.strip(), path, title.no,
           f"InParm says {title.comment.strip()!r}; MCML 1.2.2 writes its input in cm ('cm is used.')")
    if len(tokens) < 2:
        raise ProfileFileError(f"{path}: line {title.no}: block InParm is truncated (no output-file line)")
    rest = tokens[2:]  # output file name and its format letter
    head, rest = _take(rest, 6, path, "InParm", title.no, "photons, dz, dr, nz, nr, na")
    photons, dz, dr, nz, nr, na = head
    no_photons = tokens[2][0]
    _check(photons >= 1 and photons == int(photons), path, no_photons,
           f"photon count {photons:g} must be a positive integer")
    grid_no = tokens[3][0]
    for name, value in (("dz", dz), ("dr", dr)):
        _check(value > 0, path, grid_no, f"{name} = {value:g} cm must be > 0")
    by_no = {line.no: line for line in lines}
    if "[" in by_no[grid_no].comment:
        _check_unit(by_no[grid_no], "[cm]", path, "InParm (dz, dr)")
    sizes_no = tokens[5][0]
    for name, value, low in (("nz", nz, 1), ("nr", nr, 2), ("na", na, 1)):
        _check(value >= low and value == int(value), path, sizes_no, f"{name} = {value:g} must be an integer >= {low}")
    (n_layers,), rest = _take(rest, 1, path, "InParm", title.no, "number of layers")
    layers_no = tokens[8][0]
    _check(n_layers >= 1 and n_layers == int(n_layers), path, layers_no,
           f"number of layers {n_layers:g} must be an integer >= 1")
    n_layers = int(n_layers)
    (n_above,), rest = _take(rest, 1, path, "InParm", title.no, "n above")
    layers = []
    for k in range(n_layers):
        no = rest[0][0] if rest else title.no
        row, rest = _take(rest, 5, path, "InParm", title.no, f"layer {k + 1}: n, mua, mus, g, d")
        n, mua, mus, g, d = row
        _check(n > 0, path, no, f"layer {k + 1}: n = {n:g} must be > 0")
        _check(mua >= 0 and mus >= 0, path, no, f"layer {k + 1}: mua = {mua:g}, mus = {mus:g} /cm must be >= 0")
        _check(-1 <= g <= 1, path, no, f"layer {k + 1}: g = {g:g} must lie in [-1, 1]")
        _check(d > 0, path, no, f"layer {k + 1}: thickness {d:g} cm must be > 0")
        layers.append(McoLayer(float(n), float(mua) / _CM, float(mus) / _CM, float(g), float(d) * _CM))
    (n_below,), rest = _take(rest, 1, path, "InParm", title.no, "n below")
    _check(n_above > 0 and n_below > 0, path, title.no, f"ambient indices {n_above:g}, {n_below:g} must be > 0")
    if rest:
        raise ProfileFileError(f"{path}: line {rest[0][0]}: unexpected value {rest[0][1]!r} at the end of InParm "
                               f"({n_layers} layer(s) declared)")
    return (int(photons), float(dz) * _CM, float(dr) * _CM, int(nz), int(nr), int(na), tuple(layers), float(n_above),
            float(n_below))


def read_mco(path) -> McoRun:
    """Read an MCML 1.2.2 ASCII output file (format ``A1``) into an :class:`McoRun` in mm and 1/mm.

    Raises:
        ProfileFileError: naming the file and the line, for an unreadable, truncated or malformed file.
    """
    path = Path(path)
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as err:
        raise ProfileFileError(f"{path}: cannot read the file: {getattr(err, 'strerror', None) or err}") from None
    lines = _lines(text)
    first = next((line for line in lines if line.tokens), None)
    if first is None or first.tokens[0] != "A1":
        raise ProfileFileError(f"{path}: line {first.no if first else 1}: expected the format version 'A1' of "
                               f"MCML 1.2.2's ASCII output, found {' '.join(first.tokens) if first else 'nothing'!r}")
    seconds = math.nan
    for line in lines:
        match = re.match(r"\s*User time:\s*([0-9.eE+-]+)\s*sec", line.comment)
        if not line.tokens and match:
            seconds = float(match.group(1))
            break
    blocks = _split_blocks(lines, path)
    title, tokens = _block(blocks, "InParm", lines, path)
    photons, dz, dr, nz, nr, na, layers, n_above, n_below = _parse_inparm(tokens, title, lines, path)

    counts = {"RAT": 4, "A_l": len(layers), "A_z": nz, "Rd_r": nr, "Rd_a": na, "Tt_r": nr, "Tt_a": na,
              "A_rz": nr * nz, "Rd_ra": nr * na, "Tt_ra": nr * na}
    arrays = {}
    for name, count in counts.items():
        title, tokens = _block(blocks, name, lines, path)
        if name in _UNITS:
            _check_unit(title, _UNITS[name], path, name)
        elif name in _UNITS_ABOVE:
            for line in lines[max(0, title.no - 7) : title.no - 1]:  # MCML's comment lines above the title
                if not line.tokens and _UNIT_RE.search(line.comment):
                    _check_unit(line, _UNITS_ABOVE[name], path, name)
        what = "specular, Rd, A, Tt" if name == "RAT" else f"{count} values"
        values, extra = _take(tokens, count, path, name, title.no, what)
        if extra:
            raise ProfileFileError(f"{path}: line {extra[0][0]}: unexpected value {extra[0][1]!r} after the "
                                   f"{len(values)} values of block {name}")
        bad = values < 0
        if bad.any():
            no = tokens[int(np.argmax(bad))][0]
            raise ProfileFileError(f"{path}: line {no}: block {name} has the negative value {values[bad][0]:g}")
        arrays[name] = values
    specular, Rd, A, Tt = (float(v) for v in arrays.pop("RAT"))
    _check(specular + Rd + A + Tt <= 1.0 + 1e-3, path, blocks["RAT"][0].no,
           f"totals specular {specular:g} + Rd {Rd:g} + A {A:g} + Tt {Tt:g} exceed 1")
    edges = dr * np.arange(nr + 1)
    scaled = {k: v * _SCALE[k] for k, v in arrays.items()}
    return McoRun(
        source=str(path), photons=photons, seconds=seconds, dz=dz, dr=dr, nz=nz, nr=nr, na=na, layers=layers,
        n_above=n_above, n_below=n_below, specular=specular, Rd=Rd, A=A, Tt=Tt, r_lo=edges[:-1], r_hi=edges[1:],
        Rd_r=scaled["Rd_r"], Tt_r=scaled["Tt_r"], A_l=scaled["A_l"], A_z=scaled["A_z"], Rd_a=scaled["Rd_a"],
        Tt_a=scaled["Tt_a"], A_rz=scaled["A_rz"].reshape(nr, nz), Rd_ra=scaled["Rd_ra"].reshape(nr, na),
        Tt_ra=scaled["Tt_ra"].reshape(nr, na),
    )
