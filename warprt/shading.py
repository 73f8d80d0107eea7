"""Local shading and the specular directions (Warp device functions).

* ``reflect(d, n)``: r = d - 2 (d·n) n.
* ``refract(d, n, eta)``: Snell's law in vector form, t = η d + (η c_i - c_t) n with c_i = -d·n,
  c_t = sqrt(1 - η² (1 - c_i²)), η = n_incident / n_transmitted; n faces the incoming ray.
  Returns the zero vector under total internal reflection (radicand < 0).
* ``fresnel_exact`` / ``fresnel_schlick``: unpolarised dielectric reflectance.
* ``blinn_phong``: kd·max(0, n·l) + ks·max(0, n·h)^p, the bracket of the lecture's sum, safe for
  any exponent (0 ** 0 is 1, huge exponents underflow to 0, never NaN).
* ``mul_sat``: the product of two colours that never overflows into NaN.
"""

from __future__ import annotations

import warp as wp


@wp.func
def reflect(d: wp.vec3, n: wp.vec3) -> wp.vec3:
    return d - 2.0 * wp.dot(d, n) * n


@wp.func
def refract(d: wp.vec3, n: wp.vec3, eta: float) -> wp.vec3:
    cos_i = -wp.dot(d, n)
    k = 1.0 - eta * eta * (1.0 - cos_i * cos_i)
    if k < 0.0:
        return wp.vec3(0.0, 0.0, 0.0)
    t = eta * d + (eta * cos_i - wp.sqrt(k)) * n
    return wp.normalize(t)


@wp.func
def fresnel_exact(cos_i: float, eta_i: float, eta_t: float) -> float:
    cos_i = wp.clamp(cos_i, 0.0, 1.0)
    sin_t = (eta_i / eta_t) * wp.sqrt(wp.max(0.0, 1.0 - cos_i * cos_i))
    if sin_t >= 1.0:
        return 1.0
    cos_t = wp.sqrt(wp.max(0.0, 1.0 - sin_t * sin_t))
    r_par = (eta_t * cos_i - eta_i * cos_t) / (eta_t * cos_i + eta_i * cos_t)
    r_perp = (eta_i * cos_i - eta_t * cos_t) / (eta_i * cos_i + eta_t * cos_t)
    return 0.5 * (r_par * r_par + r_perp * r_perp)


@wp.func
def fresnel_schlick(cos_i: float, eta_i: float, eta_t: float) -> float:
    r0 = (eta_i - eta_t) / (eta_i + eta_t)
    r0 = r0 * r0
    c = wp.clamp(cos_i, 0.0, 1.0)
    if eta_i > eta_t:
        sin_t2 = (eta_i / eta_t) * (eta_i / eta_t) * (1.0 - c * c)
        if sin_t2 >= 1.0:
            return 1.0
        c = wp.sqrt(1.0 - sin_t2)
    m = 1.0 - c
    return r0 + (1.0 - r0) * m * m * m * m * m


@wp.func
def fresnel(mode: int, cos_i: float, eta_i: float, eta_t: float) -> float:
    """mode 1: Schlick, 2: exact (mode 0, no Fresnel, is handled by the caller)."""
    if mode == 1:
        return fresnel_schlick(cos_i, eta_i, eta_t)
    return fresnel_exact(cos_i, eta_i, eta_t)


@wp.func
def phong_power(x: float, p: float) -> float:
    """max(0, x)^p without NaN: 0^0 = 1, any huge p underflows to 0, and x >= 1 (n·h of float32
    unit vectors can exceed 1) gives 1 also for p = inf (a p beyond the float32 range)."""
    if p == 0.0:
        return 1.0
    if x <= 0.0:
        return 0.0
    if x >= 1.0:
        return 1.0
    return wp.exp(p * wp.log(x))


@wp.func
def blinn_phong(n: wp.vec3, l: wp.vec3, v: wp.vec3, kd: wp.vec3, ks: wp.vec3, p: float) -> wp.vec3:
    """kd max(0, n.l) + ks max(0, n.h)^p for unit n, l (to the light), v (to the viewer)."""
    ndotl = wp.dot(n, l)
    if ndotl <= 0.0:
        return wp.vec3(0.0, 0.0, 0.0)
    h = l + v
    hl = wp.length(h)
    spec = float(0.0)
    if hl > 0.0 and wp.max(ks) > 0.0:  # (the power costs a log and an exp: skipped for ks = 0)
        spec = phong_power(wp.dot(n, h / hl), p)
    return kd * ndotl + ks * spec


FLT_MAX = 3.4028234663852886e38  # the largest float32


@wp.func(inline=True)
def mul_sat(a: wp.vec3, b: wp.vec3) -> wp.vec3:
    """a·b per component for non-negative colours, never NaN or Inf: a zero (or NaN) factor gives
    0 even against Inf, and a product beyond the float32 range saturates at FLT_MAX. An
    overflowing light term times a zero weight (a coloured mirror, a coloured glass's
    transmittance) is then 0, not a NaN that ``sanitize`` would turn into the loss of every
    other contribution to that channel of the sample. Bit-identical to ``cw_mul`` otherwise."""
    out = wp.vec3(0.0, 0.0, 0.0)
    for k in range(3):
        if a[k] > 0.0 and b[k] > 0.0:
            out[k] = wp.min(a[k] * b[k], FLT_MAX)
    return out
