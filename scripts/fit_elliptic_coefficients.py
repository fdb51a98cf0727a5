"""Coefficients of kernel/src/elliptic_integrals.f90: B(m) and D(m) in Cody's form.

    D(m) = (K - E)/m        = P_D(m1) + ln(m1)      Q_D(m1),
    B(m) = (E - m1 K)/m     = P_B(m1) + ln(m1) m1   Q_B(m1),     m1 = 1 - m,

P and Q polynomials of degree 10 (Cody, Math. Comp. 19, 1965, for K and E; Cephes ellpk/ellpe).
The log singularity at m -> 1 is carried by ln(m1) exactly, so the polynomials only have to fit
functions analytic on [0, 1]. The constant terms are the exact limits m1 -> 0 (D = ln 4 - 1 -
ln(m1)/2 + ..., B = 1 + m1 ln(m1)/4 + ...), which keeps the relative error bounded for every
m1 down to the underflow; the other 2 x 10 coefficients of each function are a least-squares
fit of the relative error in 90-digit arithmetic at Chebyshev nodes of [0, 1] and at
m1 = 10**-1 ... 10**-39. References: D = (pi/4) 2F1(1/2, 3/2; 2; m),
B = (pi/4) 2F1(1/2, 1/2; 2; m).

Run with any Python that has mpmath (not a dependency of capsmech):
    python3 scripts/fit_elliptic_coefficients.py
It prints the Fortran parameter arrays and the fit's largest relative error on a dense grid
(degree 10: 7e-17 for D, 3e-17 for B, below the double rounding of the evaluation).
"""
from __future__ import annotations

import mpmath as mp

mp.mp.dps = 90
DEGREE = 10


def d_exact(m1):
    return mp.pi / 4 * mp.hyp2f1(0.5, 1.5, 2, 1 - m1)


def b_exact(m1):
    return mp.pi / 4 * mp.hyp2f1(0.5, 0.5, 2, 1 - m1)


def evaluate(p, q, shift, x):
    return mp.polyval(p[::-1], x) + mp.log(x) * x**shift * mp.polyval(q[::-1], x)


def fit(f, p0, q0, shift):
    """p, q (ascending) with p[0] = p0, q[0] = q0 fixed, least-squares in relative error."""
    nodes = [(1 - mp.cos(mp.pi * (k + mp.mpf(1) / 2) / 120)) / 2 for k in range(120)]
    nodes += [mp.mpf(10) ** -e for e in range(1, 40)] + [mp.mpf(1)]
    rows, rhs = [], []
    for x in nodes:
        fx = f(x)
        lx = mp.log(x)
        rows.append([x**i / fx for i in range(1, DEGREE + 1)] + [lx * x ** (shift + i) / fx for i in range(1, DEGREE + 1)])
        rhs.append((fx - p0 - lx * x**shift * q0) / fx)
    sol = mp.qr_solve(mp.matrix(rows), mp.matrix(rhs))[0]
    return [p0] + [sol[i] for i in range(DEGREE)], [q0] + [sol[DEGREE + i] for i in range(DEGREE)]


def fortran_array(name: str, coefficients) -> str:
    values = [mp.nstr(c, 22, min_fixed=-1, max_fixed=1).replace("e", "e") for c in coefficients]
    body = ", &\n      ".join(", ".join(f"{v}_dp" for v in values[i:i + 3]) for i in range(0, len(values), 3))
    return f"   real(dp), parameter :: {name}(0:{DEGREE}) = [ &\n      {body}]"


def main() -> None:
    test = [mp.mpf(k) / 2000 for k in range(1, 2001)] + [mp.mpf(10) ** (-mp.mpf(e) / 4) for e in range(4, 240)]
    for name, f, p0, q0, shift in [("d", d_exact, mp.log(4) - 1, mp.mpf(-1) / 2, 0),
                                   ("b", b_exact, mp.mpf(1), mp.mpf(1) / 4, 1)]:
        p, q = fit(f, p0, q0, shift)
        err = max(abs(evaluate(p, q, shift, x) / f(x) - 1) for x in test)
        print(f"! {name.upper()}: largest relative error of the fit {mp.nstr(err, 2)}")
        print(fortran_array(f"{name}_p", p))
        print(fortran_array(f"{name}_q", q))


if __name__ == "__main__":
    main()
