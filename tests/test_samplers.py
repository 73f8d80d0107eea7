"""The samplers' point sets, checked directly (``warprt.query.pixel_samples`` / ``pixel_samples_1d``
run the renderer's own ``sample_2d`` / ``sample_1d``): range, stratification, net properties and
determinism; the light samples' order (``light_sample_2d``) and the packets' draws against each
lane's. Rendered consequences (convergence rates, moiré) are in test_distribution.py and
stability/test_moire.py."""

from __future__ import annotations

import numpy as np
import pytest

from warprt.errors import RenderError
from warprt.query import pixel_samples, pixel_samples_1d

PIXELS = np.arange(0, 4000, 97)  # 42 pixels spread over a frame
DIM_FILM, DIM_LENS, DIM_TIME = 0, 1, 2


def cells(points, nx, ny):
    """Cell index of each 2D point on an nx × ny grid."""
    ix = np.minimum((points[..., 0] * nx).astype(int), nx - 1)
    iy = np.minimum((points[..., 1] * ny).astype(int), ny - 1)
    return iy * nx + ix


@pytest.mark.parametrize("sampler", ["regular", "independent", "stratified", "sobol"])
@pytest.mark.parametrize("dim", [DIM_FILM, DIM_LENS, 12345])
def test_samples_lie_in_the_unit_square(sampler, dim):
    u = pixel_samples(sampler, PIXELS, 64, dim=dim, seed=5)
    assert u.shape == (len(PIXELS), 64, 2)
    assert (u >= 0).all() and (u < 1).all()


@pytest.mark.parametrize("spp, nx, ny", [(4, 2, 2), (16, 4, 4), (8, 4, 2), (12, 4, 3), (7, 7, 1)])
def test_stratified_puts_one_jittered_sample_in_each_grid_cell(spp, nx, ny):
    for dim in (DIM_FILM, DIM_LENS):
        u = pixel_samples("stratified", PIXELS, spp, dim=dim, seed=3)
        for row in cells(u, nx, ny):
            assert sorted(row) == list(range(spp))
    # jittered, not centred: the offsets inside the cells are spread over the cell
    frac = (u[..., 0] * nx) % 1.0
    assert frac.min() < 0.1 and frac.max() > 0.9


@pytest.mark.parametrize("spp, nx, ny", [(4, 2, 2), (16, 4, 4), (8, 4, 2)])
def test_regular_is_the_grid_of_cell_centres_in_every_pixel(spp, nx, ny):
    u = pixel_samples("regular", PIXELS, spp, dim=DIM_FILM, seed=3)
    cx, cy = np.meshgrid((np.arange(nx) + 0.5) / nx, (np.arange(ny) + 0.5) / ny)
    expected = np.stack([cx.ravel(), cy.ravel()], 1)
    for row in u:
        np.testing.assert_allclose(row, expected, atol=1e-7)


@pytest.mark.parametrize("m", [2, 4, 6])
def test_sobol_power_of_two_prefix_is_a_0_m_2_net(m):
    """Owen-scrambled Sobol (first two dimensions): every prefix of 2^m points puts exactly one
    point in each elementary box of area 2^-m (2^a × 2^(m-a) grids, all a)."""
    n = 2 ** m
    u = pixel_samples("sobol", PIXELS, n, dim=DIM_LENS, seed=11)
    for a in range(m + 1):
        for row in cells(u, 2 ** a, 2 ** (m - a)):
            assert sorted(row) == list(range(n)), (a, row)


def test_independent_samples_are_uniform():
    u = pixel_samples("independent", PIXELS, 256, dim=DIM_FILM, seed=1).reshape(-1, 2)
    counts = np.bincount(cells(u, 4, 4), minlength=16)
    expected = len(u) / 16
    chi2 = float(((counts - expected) ** 2 / expected).sum())
    assert chi2 < 40.0, chi2  # 15 degrees of freedom: P(chi2 > 40) ≈ 5e-4
    # not stratified: some pixel's 16 samples miss a cell of the 4 x 4 grid
    u16 = pixel_samples("independent", PIXELS, 16, dim=DIM_FILM, seed=1)
    assert any(len(set(row)) < 16 for row in cells(u16, 4, 4))


@pytest.mark.parametrize("spp", [2, 5, 16, 48])
def test_time_samples_fill_every_stratum_of_the_shutter(spp):
    """The shutter time is a 1D sample: ``stratified`` puts one jittered sample in each of the
    spp equal intervals (the first coordinate of an nx × ny grid filled only nx of them),
    ``regular`` takes their centres, the same in every pixel."""
    t = pixel_samples_1d("stratified", PIXELS, spp, dim=DIM_TIME, seed=4)
    assert t.shape == (len(PIXELS), spp) and (t >= 0).all() and (t <= 1).all()
    for row in np.minimum((t * spp).astype(int), spp - 1):
        assert sorted(row) == list(range(spp))
    assert len(np.unique(t)) > spp  # jittered: different in every pixel
    r = pixel_samples_1d("regular", PIXELS, spp, dim=DIM_TIME, seed=4)
    centres = (np.arange(spp) + 0.5) / spp
    for row in r:
        np.testing.assert_allclose(np.sort(row), centres, atol=1e-7)
    np.testing.assert_array_equal(r, np.broadcast_to(r[0], r.shape))


@pytest.mark.parametrize("sampler", ["independent", "sobol"])
def test_1d_samples_of_independent_and_sobol_are_the_first_2d_coordinate(sampler):
    t = pixel_samples_1d(sampler, PIXELS, 16, dim=DIM_TIME, seed=9)
    u = pixel_samples(sampler, PIXELS, 16, dim=DIM_TIME, seed=9)
    np.testing.assert_array_equal(t, u[..., 0])
    if sampler == "sobol":  # van der Corput: one point in each of the 16 intervals
        for row in np.minimum((t * 16).astype(int), 15):
            assert sorted(row) == list(range(16))


@pytest.mark.parametrize("sampler", ["independent", "stratified", "sobol"])
def test_samples_are_a_function_of_seed_pixel_index_and_dimension(sampler):
    a = pixel_samples(sampler, PIXELS, 16, dim=DIM_FILM, seed=7)
    np.testing.assert_array_equal(a, pixel_samples(sampler, PIXELS, 16, dim=DIM_FILM, seed=7))
    # drawing more samples than planned does not change the first ones
    np.testing.assert_array_equal(a, pixel_samples(sampler, PIXELS, 16, dim=DIM_FILM, seed=7, count=40)[:, :16])
    for other in (pixel_samples(sampler, PIXELS, 16, dim=DIM_FILM, seed=8),
                  pixel_samples(sampler, PIXELS, 16, dim=DIM_LENS, seed=7)):
        assert np.mean(a == other) < 0.01
    assert np.mean(a[0] == a[1]) < 0.01  # pixels differ


def test_unknown_sampler_is_an_error():
    with pytest.raises(RenderError, match="unknown sampler 'halton'"):
        pixel_samples("halton", [0], 4)
    with pytest.raises(RenderError, match="unknown sampler"):
        pixel_samples_1d("halton", [0], 4)


def test_sobol_points_drawn_for_a_packet_are_each_lanes_own():
    """``sampling.sobol_packet`` (a packet's 8 lanes at once, clang vectors on the CPU) gives every
    lane the point ``sample_2d_keyed`` gives it alone, bit for bit: random pixel keys, sample
    indices over the whole 32-bit range and dimension keys, high bits included."""
    import warp as wp

    from warprt.accel import PacketF, PacketI, PacketU
    from warprt.sampling import SAMPLER_SOBOL, sample_2d_keyed, sobol_packet

    @wp.kernel(enable_backward=False)
    def both(keys: wp.array(dtype=wp.uint32), index: wp.array(dtype=wp.int32), dims: wp.array(dtype=wp.uint32),
             packed: wp.array(dtype=wp.vec2), alone: wp.array(dtype=wp.vec2)):
        g = wp.tid()
        k8 = PacketU()
        i8 = PacketI()
        for lane in range(8):
            k8[lane] = keys[g * 8 + lane]
            i8[lane] = index[g * 8 + lane]
        x = PacketF()
        y = PacketF()
        sobol_packet(k8, i8, dims[g], x, y)
        for lane in range(8):
            packed[g * 8 + lane] = wp.vec2(x[lane], y[lane])
            alone[g * 8 + lane] = sample_2d_keyed(SAMPLER_SOBOL, keys[g * 8 + lane], index[g * 8 + lane], 64, dims[g])

    rng = np.random.default_rng(11)
    n = 8 * 4096
    keys = rng.integers(0, 2 ** 32, n, dtype=np.uint64).astype(np.uint32)
    index = np.concatenate([np.arange(n // 2), rng.integers(0, 2 ** 31, n - n // 2)]).astype(np.int32)
    dims = rng.integers(0, 2 ** 32, n // 8, dtype=np.uint64).astype(np.uint32)
    dims[:4] = (DIM_FILM, DIM_LENS, DIM_TIME, 0x80000000)
    packed = wp.zeros(n, dtype=wp.vec2, device="cpu")
    alone = wp.zeros(n, dtype=wp.vec2, device="cpu")
    wp.launch(both, dim=n // 8, device="cpu", inputs=[wp.array(keys, dtype=wp.uint32, device="cpu"),
                                                     wp.array(index, dtype=wp.int32, device="cpu"),
                                                     wp.array(dims, dtype=wp.uint32, device="cpu"), packed, alone])
    a, b = packed.numpy(), alone.numpy()
    assert a.tobytes() == b.tobytes()
    assert (a >= 0).all() and (a < 1).all() and len(np.unique(a[:, 0])) > n // 2


def _light_draws(sampler_id, keys, samples, ns, ks, dims):
    """``light_sample_2d`` and ``sample_2d_keyed`` at ``sample * ns + k`` for each entry, and
    ``sobol_split_setup`` then ``sobol_split_draw`` for the entries in groups of 8 (one ns, k and
    dimension a group)."""
    import warp as wp

    from warprt.accel import PacketF, PacketI, PacketU
    from warprt.sampling import SplitDraws, light_sample_2d, sample_2d_keyed, sobol_split_draw, sobol_split_setup

    @wp.kernel(enable_backward=False)
    def draws(sampler: int, keys: wp.array(dtype=wp.uint32), samples: wp.array(dtype=wp.int32),
              ns: wp.array(dtype=wp.int32), ks: wp.array(dtype=wp.int32), dims: wp.array(dtype=wp.uint32),
              light: wp.array(dtype=wp.vec2), plain: wp.array(dtype=wp.vec2), packed: wp.array(dtype=wp.vec2)):
        g = wp.tid()
        k8 = PacketU()
        s8 = PacketI()
        for lane in range(8):
            i = g * 8 + lane
            k8[lane] = keys[i]
            s8[lane] = samples[i]
            light[i] = light_sample_2d(sampler, keys[i], samples[i], ns[i], ks[i], 16, dims[i])
            plain[i] = sample_2d_keyed(sampler, keys[i], samples[i] * ns[i] + ks[i], 16 * ns[i], dims[i])
        x = PacketF()
        y = PacketF()
        if ns[g * 8] >= 2 and (ns[g * 8] & (ns[g * 8] - 1)) == 0:
            state = SplitDraws()
            sobol_split_setup(k8, s8, ns[g * 8], dims[g * 8], state)
            sobol_split_draw(state, ns[g * 8], ks[g * 8], x, y)
        for lane in range(8):
            packed[g * 8 + lane] = wp.vec2(x[lane], y[lane])

    n = len(keys)
    out = [wp.zeros(n, dtype=wp.vec2, device="cpu") for _ in range(3)]
    wp.launch(draws, dim=n // 8, device="cpu",
              inputs=[sampler_id, wp.array(keys, dtype=wp.uint32, device="cpu"),
                      wp.array(samples, dtype=wp.int32, device="cpu"), wp.array(ns, dtype=wp.int32, device="cpu"),
                      wp.array(ks, dtype=wp.int32, device="cpu"), wp.array(dims, dtype=wp.uint32, device="cpu"), *out])
    return [o.numpy() for o in out]


@pytest.mark.parametrize("ns", [2, 4, 8, 16])
def test_split_light_samples_are_the_same_points_in_quadrant_order(ns):
    """With ``sobol`` and ns a power of two, a camera sample's ns light samples
    (``sampling.light_sample_2d``) are the points ``sample_2d_keyed`` draws at indices
    sample * ns + [0, ns), bit for bit, in another order: the k-th in the light square's quadrant
    k % 4 (for ns = 2, the k-th in half k of x); the 8 lanes' draws of a packet
    (``sobol_split_setup``, ``sobol_split_draw``) are each lane's own, bit for bit. Random pixel
    and dimension keys, camera samples up to 2^27 / ns."""
    from warprt.sampling import SAMPLER_SOBOL

    rng = np.random.default_rng(ns)
    cams = 1024  # camera samples, each with its ns draws
    keys = np.repeat(rng.integers(0, 2 ** 32, cams, dtype=np.uint64).astype(np.uint32), ns)
    dims = np.repeat(rng.integers(0, 2 ** 32, cams, dtype=np.uint64).astype(np.uint32), ns)
    samples = np.repeat(np.concatenate([np.arange(cams // 2), rng.integers(0, 2 ** 27 // ns, cams // 2)]), ns)
    ks = np.tile(np.arange(ns), cams)
    light, plain, _ = _light_draws(SAMPLER_SOBOL, keys, samples.astype(np.int32), np.full(len(ks), ns, np.int32),
                                   ks.astype(np.int32), dims)
    light, plain = light.reshape(cams, ns, 2), plain.reshape(cams, ns, 2)
    for a, b in zip(light, plain):
        assert sorted(map(tuple, a)) == sorted(map(tuple, b))
    assert np.mean(light == plain) < 0.75  # another order, not the same one
    k = np.arange(ns)
    np.testing.assert_array_equal(light[..., 0] >= 0.5, np.broadcast_to(k & 1 == 1, (cams, ns)))
    if ns >= 4:
        np.testing.assert_array_equal(light[..., 1] >= 0.5, np.broadcast_to(k & 2 == 2, (cams, ns)))
    # a packet's lanes: 8 random pixels and samples, one k and dimension
    lanes = cams // 8 * 8
    keys8 = rng.integers(0, 2 ** 32, lanes, dtype=np.uint64).astype(np.uint32)
    samples8 = rng.integers(0, 2 ** 27 // ns, lanes).astype(np.int32)
    ks8 = np.repeat(rng.integers(0, ns, lanes // 8), 8).astype(np.int32)
    dims8 = np.repeat(rng.integers(0, 2 ** 32, lanes // 8, dtype=np.uint64).astype(np.uint32), 8)
    light8, _, packed8 = _light_draws(SAMPLER_SOBOL, keys8, samples8, np.full(lanes, ns, np.int32), ks8, dims8)
    assert packed8.tobytes() == light8.tobytes()


@pytest.mark.parametrize("sampler, ns", [("sobol", 1), ("sobol", 3), ("sobol", 6), ("stratified", 4),
                                         ("independent", 4), ("regular", 2)])
def test_other_light_samples_are_drawn_at_sample_times_ns_plus_k(sampler, ns):
    """``light_sample_2d`` is ``sample_2d_keyed`` at index sample * ns + k where the quadrant order
    does not apply (another sampler, or ns not a power of two of at least 2)."""
    from warprt.sampling import SAMPLER_IDS

    rng = np.random.default_rng(ns)
    n = 8 * 64
    keys = rng.integers(0, 2 ** 32, n, dtype=np.uint64).astype(np.uint32)
    dims = rng.integers(0, 2 ** 32, n, dtype=np.uint64).astype(np.uint32)
    samples = rng.integers(0, 16, n).astype(np.int32)
    ks = rng.integers(0, ns, n).astype(np.int32)
    light, plain, _ = _light_draws(SAMPLER_IDS[sampler], keys, samples, np.full(n, ns, np.int32), ks, dims)
    assert light.tobytes() == plain.tobytes()
