r'''Least-squares helpers shared by the fits and comparisons: scipy's forward difference, remembered

SYNOPSIS

    from harness.least_squares import forward_difference, remembering

    fun, jac = remembering(residuals, lambda x, f0: forward_difference(residuals, x, f0))
    sol = scipy.optimize.least_squares(fun, x0, jac=jac, method="lm")

The jpl calibrator's Levenberg-Marquardt and the comparison's rotation fit
both differentiate by scipy's own '2-point' rule (bit for bit) and remember
the last point's residuals and Jacobian, so nothing is evaluated twice.
'''

import numpy as np

# scipy's default relative step of a forward difference: sqrt(float64 eps)
FORWARD_STEP = np.finfo(np.float64).eps ** 0.5


def forward_steps(x):
    r'''The steps of forward_difference: sqrt(eps) max(1, |x_i|), signed as x_i (+ for 0)'''
    sign = (x >= 0).astype(x.dtype) * 2 - 1
    return (FORWARD_STEP * sign * np.maximum(1.0, np.abs(x))).astype(x.dtype)


def forward_difference(f, x, f0):
    r'''The Jacobian (M,N) of f at x by forward differences, as scipy's '2-point' computes it

SYNOPSIS

    J = forward_difference(residuals, x, residuals(x))

scipy.optimize.least_squares(jac="2-point") differences, bit for bit
(scipy.optimize._numdiff.approx_derivative without bounds): the step of x_i
is sqrt(eps) max(1, |x_i|), signed as x_i (+ for 0), and column i is
(f(x + h_i e_i) - f0) / ((x_i + h_i) - x_i).
'''
    h = forward_steps(x)
    J_T = np.empty((x.size, f0.size))
    for i in range(x.size):
        x1 = np.copy(x)
        x1[i] = x[i] + h[i]
        J_T[i] = (f(x1) - f0) / ((x[i] + h[i]) - x[i])
    return J_T.T


def remembering(evaluate, jacobian_at):
    r'''(fun, jac) for scipy.optimize.least_squares that remember the last point

SYNOPSIS

    fun, jac = remembering(residuals, lambda x, f0: forward_difference(residuals, x, f0))
    scipy.optimize.least_squares(fun, x0, jac=jac, method="lm")

fun(x) = evaluate(x); jac(x) = jacobian_at(x, evaluate(x)), reusing the
residuals of the last point fun was called at and the Jacobian of the last
point jac was called at (scipy asks for the Jacobian at the solution again
when MINPACK returns).
'''
    last_f, last_J = {}, {}

    def fun(x):
        f = evaluate(x)
        last_f.clear()
        last_f[x.tobytes()] = f
        return f

    def jac(x):
        key = x.tobytes()
        J = last_J.get(key)
        if J is None:
            f0 = last_f.get(key)
            J = jacobian_at(x, evaluate(x) if f0 is None else f0)
            last_J.clear()
            last_J[key] = J
        return J

    return fun, jac
