r'''harness.verdict.corner_correlation and line_correlation, batched (every end's normal
equations of an image's board lines in one solve), against the one-solve-at-a-time code they
replaced (kept here as the reference, verbatim but for its names): a real record's inputs
(tests/data/corner_correlation_cam17_cahvore.npz: camera 17 as CAHVORE, the AprilTag grid
through the realistic sensor, seed 0, 612 of 864 corners kept, response-corners.toml's job)
and constructed lines with the cases the solve leaves out'''

from pathlib import Path

import numpy as np

from harness import verdict

DATA = Path(__file__).parent / "data" / "corner_correlation_cam17_cahvore.npz"


# --- the reference: harness/verdict.py's code before the batching (commit 5e801f5) ---

def _ref_span_degree(h, tol=1e-6):
    r'''The degree of a span's polynomial from its functional h (6,) on a board line's
quintic (targets.tag_edges.SPAN_RECORD): the fit follows a polynomial up to its degree
exactly (h_l ~ 0 for l <= degree)'''
    big = np.abs(h) > tol * max(np.abs(h).max(), 1e-300)
    return int(np.argmax(big)) - 1 if big.any() else 5


def _ref_line_correlation(ends, pieces):
    r'''(m, m) the correlation of m edge ends' errors across one board line

ends: [(u_a, u_b, tc, degree, r0, r1)] each end's edge from corner a (tau -1) to b (tau 1)
in the line's board coordinate u, its corner's tau (+-1), its span's polynomial degree and
its reach r0 < r1 in u; pieces: [(u0, u1)] where the line has pixels (its tags' edges).

Each end is the least-squares polynomial of its degree in its own tau over the pixels of
its reach, evaluated at its corner: a linear function of the pixels' noise, phi(u)
(targets.tag_edges._span_choice's variance is its sum of squares). With the noise and the
pixels' information alike along the line (the light level and contrast left out: a
symmetric profile's are nearly orthogonal to its position), two ends' covariance is the
integral of phi_a phi_b over the pixels both reach.'''
    cuts = sorted({x for e in ends for x in e[4:6]})
    x, w = [], []
    for u0, u1 in pieces:
        b = [u0] + [c for c in cuts if u0 < c < u1] + [u1]
        for a0, a1 in zip(b[:-1], b[1:], strict=True):
            x.append(0.5 * (a0 + a1) + 0.5 * (a1 - a0) * verdict._LINE_NODES[0])
            w.append(0.5 * (a1 - a0) * verdict._LINE_NODES[1])
    x, w = np.concatenate(x), np.concatenate(w)
    Phi = np.zeros((len(ends), len(x)))
    for k, (ua, ub, tc, deg, r0, r1) in enumerate(ends):
        m = (x >= r0) & (x <= r1)
        V = np.vander(2.0 * (x[m] - ua) / (ub - ua) - 1.0, deg + 1, increasing=True)
        A = V.T @ (V * w[m, None])
        if m.sum() <= deg or not np.all(np.isfinite(A)):
            continue
        try:
            Phi[k, m] = V @ np.linalg.solve(A, tc ** np.arange(deg + 1.0))
        except np.linalg.LinAlgError:
            continue
    C = (Phi * w) @ Phi.T
    d = np.sqrt(np.diag(C))
    ok = d > 0
    out = np.eye(len(ends))
    out[np.ix_(ok, ok)] = C[np.ix_(ok, ok)] / np.outer(d[ok], d[ok])
    np.fill_diagonal(out, 1.0)
    return out


def _ref_corner_correlation(obs, pose):
    r'''[(rows, C)] per image: the rows (2n,) of its n fitted points (x, y interleaved, as
Linearisation's) and C (2n, 2n) their errors' correlation across the board lines their
edges share, unit diagonal; None without tag edges' span records (Observations
.corner_spans) or predictions (corner_sigma_px)

A tag-edge corner is where two edges' curves meet; each edge is fitted over a span of its
board line (the edge alone, with its neighbour's nearer part, or the whole line:
targets.tag_edges._span_choice), and corners whose spans share pixels err alike across
that line (the pupil job's 120 draws: 0.67 across the gap to the next tag, 0.33 at the
two ends of one edge). Each corner's error is split into its two lines' normals
(orthonormalised), each line's ends correlated by line_correlation, its reach and degree
from the span records; C is then a sum of correlation matrices, positive semidefinite.'''
    spans = getattr(obs, "corner_spans", None)
    if spans is None or getattr(obs, "corner_sigma_px", None) is None:
        return None
    fitted = verdict._fitted_points(obs, pose)
    if fitted is None:
        return None
    pi, pt = fitted
    out = []
    row0 = 0
    for i in np.unique(pi):
        pts = pt[pi == i]
        n = len(pts)
        rows = np.arange(row0, row0 + 2 * n)
        row0 += 2 * n
        C = np.eye(2 * n)
        sp, q, pb = spans[i], obs.q[i], obs.p_board[i][:, :2]
        # each board line's edge ends: (corner, slot, (u_a, u_b, tc, degree, r0, r1),
        # the edge's (u_a, u_b)); each corner's edges' image normals
        lines, normal = {}, np.full((n, 2, 2), np.nan)
        for k, p in enumerate(pts):
            for slot in (0, 1):
                r = sp[p, slot]
                if not np.all(np.isfinite(r)):
                    continue
                o = int(r[-1])
                a, b, tc = (o, p, 1.0) if slot == 0 else (p, o, -1.0)
                if not (np.all(np.isfinite(q[a])) and np.all(np.isfinite(q[b]))):
                    continue
                d = pb[b] - pb[a]
                ax = int(np.argmax(np.abs(d)))
                L = float(np.hypot(*d))
                if not L > 0 or abs(d[1 - ax]) > 1e-9 * L:
                    continue
                key = (ax, round(float(pb[a][1 - ax]), 9))
                ua, ub = float(pb[a][ax]), float(pb[b][ax])
                r0, r1 = sorted((ua + 0.5 * (r[-3] + 1.0) * (ub - ua),
                                 ua + 0.5 * (r[-2] + 1.0) * (ub - ua)))
                e = q[b] - q[a]
                normal[k, slot] = np.array([-e[1], e[0]]) / np.hypot(*e)
                lines.setdefault(key, []).append(
                    (k, slot, (ua, ub, tc, _ref_span_degree(r[:6]), r0, r1), (ua, ub)))
        # each corner's two directions: its first edge's normal, the second's made
        # orthogonal to it (its sign kept: the same for every end of a line)
        unit = normal.copy()
        for k in range(n):
            n0, n1 = normal[k]
            if np.all(np.isfinite(n0)) and np.all(np.isfinite(n1)):
                v = n1 - (n1 @ n0) * n0
                unit[k, 1] = v / np.hypot(*v)
        C4 = np.zeros((n, n, 2, 2))
        for members in lines.values():
            if len(members) < 2:
                continue
            pieces = sorted({tuple(sorted(m[3])) for m in members})
            R = _ref_line_correlation([m[2] for m in members], pieces)
            k = np.array([m[0] for m in members])
            U = unit[k, [m[1] for m in members]]
            R = np.where((k[:, None] != k[None, :]) & np.isfinite(U).all(-1)[:, None]
                         & np.isfinite(U).all(-1)[None, :], R, 0.0)
            np.add.at(C4, (k[:, None], k[None, :]), R[..., None, None]
                      * np.nan_to_num(U)[:, None, :, None] * np.nan_to_num(U)[None, :, None, :])
        C += C4.transpose(0, 2, 1, 3).reshape(2 * n, 2 * n)
        out.append((rows, C))
    return out


class _Obs:
    r'''What corner_correlation reads of Observations'''

    def __init__(self, **f):
        self.__dict__.update(f)
        self.Nposes = self.found.shape[0]


def _record():
    with np.load(DATA) as z:
        f = {k: z[k] for k in z.files}
    pose = f.pop("pose")
    return _Obs(**f), pose


def test_corner_correlation_of_a_real_record_is_the_reference_s():
    obs, pose = _record()
    ref = _ref_corner_correlation(obs, pose)
    new = verdict.corner_correlation(obs, pose)
    assert len(new) == len(ref) == 6
    n_corr = 0
    for (r0, C0), (r1, C1) in zip(ref, new, strict=True):
        assert np.array_equal(r0, r1)
        # correlations (|c| <= 1): the same to rounding
        np.testing.assert_allclose(C1, C0, rtol=1e-9, atol=1e-12)
        n_corr += int(np.count_nonzero(C0 - np.diag(np.diag(C0))))
    # the record exercises the correlation: most corners share lines (the same entries set)
    assert n_corr > 10000


def test_line_correlation_is_the_reference_s_on_constructed_lines():
    rng = np.random.default_rng(7)
    for _ in range(40):
        # a board line of 2-6 tags' edges (length 1, gaps 0.3), ends of degree 0-5 over
        # reaches of one edge, an edge and its neighbour's part, or the whole line
        nt = int(rng.integers(2, 7))
        pieces = [(1.3 * t, 1.3 * t + 1.0) for t in range(nt)]
        ends = []
        for _ in range(int(rng.integers(2, 2 * nt + 1))):
            t = int(rng.integers(nt))
            ua, ub = pieces[t]
            kind = rng.integers(3)
            r0, r1 = ((ua, ub) if kind == 0 else
                      (max(0.0, ua - 0.65), ub) if kind == 1 else (0.0, pieces[-1][1]))
            ends.append((ua, ub, float(rng.choice([-1.0, 1.0])), int(rng.integers(6)),
                         r0, r1))
        np.testing.assert_allclose(verdict.line_correlation(ends, pieces),
                                   _ref_line_correlation(ends, pieces), rtol=1e-9,
                                   atol=1e-12)


def test_ends_the_solve_leaves_out_stay_uncorrelated():
    # a zero-length edge (u_a = u_b) and a reach in the gap between two tags (no pixels):
    # uncorrelated rows, as the reference leaves them; a short reach is cut out of its
    # piece with nodes of its own (8, for degree <= 5), so it is fitted
    pieces = [(0.0, 1.0), (1.3, 2.3)]
    ends = [(0.0, 1.0, 1.0, 3, 0.0, 2.3), (1.3, 2.3, -1.0, 3, 0.0, 2.3),
            (0.5, 0.5, 1.0, 1, 0.0, 1.0), (0.0, 1.0, 1.0, 2, 1.05, 1.25),
            (0.0, 1.0, -1.0, 5, 0.4, 0.41)]
    R = verdict.line_correlation(ends, pieces)
    with np.errstate(all="ignore"):     # the reference divides by the zero length
        ref = _ref_line_correlation(ends, pieces)
    np.testing.assert_allclose(R, ref, rtol=1e-9, atol=1e-12)
    assert R[0, 1] > 0.5
    assert np.array_equal(R[2:4, :], np.eye(5)[2:4, :])
    assert R[0, 4] != 0.0


def test_span_degree_per_record():
    # degree d: h_l ~ 0 for l <= d; all zero: 5 (the quintic)
    h = np.array([[0.0, 0.0, 1e-12, 0.3, 0.1, 0.2], [1.0, 0.5, 0.1, 0.0, 0.0, 0.0],
                  [0.0] * 6])
    assert verdict._span_degree(h).tolist() == [2, -1, 5]
    assert [_ref_span_degree(x) for x in h] == [2, -1, 5]
