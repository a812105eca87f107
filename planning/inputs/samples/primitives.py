"""Stage 1, reference samples: the implicit primitives the femur-like surface is built from (mm).

Each primitive (:class:`_Sphere`, :class:`_Ellipsoid`, :class:`_Capsule`, :class:`_BentTube`)
gives a value close to a signed distance (mm, negative inside) with ``value(x)``, the value and
its gradient with ``eval(x)``, and samples its own surface uniformly per unit area, exactly on its
zero set, with the exact outward normal there (``sample(rng, density)``, density in points/mm^2).
``lo``/``hi`` bound the primitive. :mod:`planning.inputs.samples.femur` blends them.
"""

from __future__ import annotations

import math

import numpy as np


def _norm_rows(v):
    return np.sqrt(np.einsum("ij,ij->i", v, v))


def _random_unit(rng, m):
    v = rng.normal(size=(m, 3))
    return v / _norm_rows(v)[:, None]


class _Sphere:
    def __init__(self, name, centre, radius):
        self.name, self.c, self.r = name, np.asarray(centre, float), float(radius)
        self.lo, self.hi = self.c - self.r, self.c + self.r

    def value(self, x):
        return _norm_rows(x - self.c) - self.r

    def eval(self, x):
        v = x - self.c
        dist = _norm_rows(v)
        return dist - self.r, v / np.maximum(dist, 1e-300)[:, None]

    def sample(self, rng, density):
        u = _random_unit(rng, round(density * 4.0 * math.pi * self.r**2))
        return self.c + self.r * u, u


class _Ellipsoid:
    """Axis-aligned ellipsoid, semi-axes ``a``. Value: the first-order distance k0 (k0 - 1) / k1,
    k0 = |q/a|, k1 = |q/a^2| (q = x - c): zero exactly on the ellipsoid, where its gradient is the
    exact unit normal."""

    def __init__(self, name, centre, semi_axes):
        self.name, self.c, self.a = name, np.asarray(centre, float), np.asarray(semi_axes, float)
        self.lo, self.hi = self.c - self.a, self.c + self.a

    def _k(self, x):
        qa = (x - self.c) / self.a
        qa2 = qa / self.a
        k0 = _norm_rows(qa)
        k1 = np.maximum(_norm_rows(qa2), 1e-300)
        return qa2, k0, k1

    def value(self, x):
        _, k0, k1 = self._k(x)
        return k0 * (k0 - 1.0) / k1

    def eval(self, x):
        qa2, k0, k1 = self._k(x)
        g0 = qa2 / np.maximum(k0, 1e-300)[:, None]           # grad k0
        g1 = qa2 / (self.a * self.a) / k1[:, None]           # grad k1
        grad = (((2.0 * k0 - 1.0) * k1)[:, None] * g0 - (k0 * (k0 - 1.0))[:, None] * g1) \
            / (k1 * k1)[:, None]
        return k0 * (k0 - 1.0) / k1, grad

    def sample(self, rng, density):
        a = self.a
        amin = a.min()
        m = round(density * 4.0 * math.pi * a.prod() / amin)
        u = _random_unit(rng, m)
        w = _norm_rows(u / a)                      # area element / (a1 a2 a3) on the unit sphere
        keep = rng.random(m) < w * amin            # rejection -> uniform per unit area
        u, w = u[keep], w[keep]
        return self.c + u * a, (u / a) / w[:, None]


class _Capsule:
    def __init__(self, name, a, b, radius):
        self.name = name
        self.a, self.b, self.r = np.asarray(a, float), np.asarray(b, float), float(radius)
        self.len = float(np.linalg.norm(self.b - self.a))
        self.t = (self.b - self.a) / self.len
        self.lo = np.minimum(self.a, self.b) - self.r
        self.hi = np.maximum(self.a, self.b) + self.r

    def _v(self, x):
        s = np.clip((x - self.a) @ self.t, 0.0, self.len)
        return x - (self.a + s[:, None] * self.t)

    def value(self, x):
        return _norm_rows(self._v(x)) - self.r

    def eval(self, x):
        v = self._v(x)
        dist = _norm_rows(v)
        return dist - self.r, v / np.maximum(dist, 1e-300)[:, None]

    def sample(self, rng, density):
        e1 = np.cross(self.t, [0.0, 0.0, 1.0])
        e1 /= np.linalg.norm(e1)
        e2 = np.cross(self.t, e1)
        mc = round(density * 2.0 * math.pi * self.r * self.len)
        s = rng.uniform(0.0, self.len, mc)
        ph = rng.uniform(0.0, 2.0 * math.pi, mc)
        nc = np.cos(ph)[:, None] * e1 + np.sin(ph)[:, None] * e2
        pc = self.a + s[:, None] * self.t + self.r * nc
        u = _random_unit(rng, round(density * 4.0 * math.pi * self.r**2))
        cen = np.where((u @ self.t >= 0.0)[:, None], self.b, self.a)
        return np.vstack((pc, cen + self.r * u)), np.vstack((nc, u))


class _BentTube:
    """Tube along X over [x0, x1]: centre line y0 = shift_y u, z0 = bow_z (1 - u^2) and radius
    r = r_mid + (r_end - r_mid) u^2, u = (x - xm) / half in [-1, 1]; half spheres beyond the ends.
    Value: radial distance in the cross-section x = const minus r(x), within 1 % of the distance
    (slopes < 0.1); zero exactly on the parametrised tube (x, y0 + r cos phi, z0 + r sin phi)."""

    def __init__(self, name, x0, x1, r_mid, r_end, bow_z, shift_y):
        self.name = name
        self.x0, self.x1 = float(x0), float(x1)
        self.xm, self.half = 0.5 * (x0 + x1), 0.5 * (x1 - x0)
        self.r_mid, self.r_end, self.bow_z, self.shift_y = r_mid, r_end, bow_z, shift_y
        rmax = max(r_mid, r_end)
        self.lo = np.array([x0 - rmax, -abs(shift_y) - rmax, min(0.0, bow_z) - rmax])
        self.hi = np.array([x1 + rmax, abs(shift_y) + rmax, max(0.0, bow_z) + rmax])

    def _line(self, x):
        u = (x - self.xm) / self.half
        r = self.r_mid + (self.r_end - self.r_mid) * u * u
        dr = 2.0 * (self.r_end - self.r_mid) * u / self.half
        dy0 = np.full_like(u, self.shift_y / self.half)
        dz0 = -2.0 * self.bow_z * u / self.half
        return r, dr, self.shift_y * u, dy0, self.bow_z * (1.0 - u * u), dz0

    def _d(self, x):
        t = np.clip(x[:, 0], self.x0, self.x1)
        r, dr, y0, dy0, z0, dz0 = self._line(t)
        dx, dy, dz = x[:, 0] - t, x[:, 1] - y0, x[:, 2] - z0
        return np.sqrt(dx * dx + dy * dy + dz * dz), r, dr, dx, dy, dz, dy0, dz0

    def value(self, x):
        rho, r = self._d(x)[:2]
        return rho - r

    def eval(self, x):
        rho, r, dr, dx, dy, dz, dy0, dz0 = self._d(x)
        inside = dx == 0.0
        rs = np.maximum(rho, 1e-300)
        gx = dx / rs - np.where(inside, (dy * dy0 + dz * dz0) / rs + dr, 0.0)
        return rho - r, np.column_stack((gx, dy / rs, dz / rs))

    def sample(self, rng, density):
        xs = np.linspace(self.x0, self.x1, 257)
        r, dr, _, dy0, _, dz0 = self._line(xs)
        gmax = float(np.max(r * np.sqrt(1.0 + (np.abs(dy0) + np.abs(dz0) + np.abs(dr)) ** 2)))
        m = round(density * (self.x1 - self.x0) * 2.0 * math.pi * gmax)
        x = rng.uniform(self.x0, self.x1, m)
        ph = rng.uniform(0.0, 2.0 * math.pi, m)
        r, dr, y0, dy0, z0, dz0 = self._line(x)
        c, s = np.cos(ph), np.sin(ph)
        slope = dy0 * c + dz0 * s + dr
        # area element r sqrt(1 + slope^2) dx dphi: rejection -> uniform per unit area
        keep = rng.random(m) * gmax < r * np.sqrt(1.0 + slope * slope)
        x, c, s, r, y0, z0, slope = x[keep], c[keep], s[keep], r[keep], y0[keep], z0[keep], slope[keep]
        p = np.column_stack((x, y0 + r * c, z0 + r * s))
        n = np.column_stack((-slope, c, s))
        n /= _norm_rows(n)[:, None]
        caps_p, caps_n = [p], [n]
        for xe, sign in ((self.x0, -1.0), (self.x1, 1.0)):   # end caps, normally buried
            re, _, ye, _, ze, _ = self._line(np.array([xe]))
            u = _random_unit(rng, 2 * round(density * 2.0 * math.pi * re[0] ** 2))
            u = u[u[:, 0] * sign > 0.0]
            caps_p.append(np.array([xe, ye[0], ze[0]]) + re[0] * u)
            caps_n.append(u)
        return np.vstack(caps_p), np.vstack(caps_n)
