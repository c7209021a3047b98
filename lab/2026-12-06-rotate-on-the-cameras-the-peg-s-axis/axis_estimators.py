"""Offline: the peg's axis from its cast top-face pixels (collect_faces.py's pickle) by three estimators, against the
simulator's, over every call and over the partly hidden faces.

    .venv/bin/python lab/2026-12-06-rotate-on-the-cameras-the-peg-s-axis/collect_faces.py RotateLenientPos-VLA-v0 5000,5001,... /tmp/rotate_faces.pkl
    .venv/bin/python lab/2026-12-06-rotate-on-the-cameras-the-peg-s-axis/axis_estimators.py
"""
import pickle, numpy as np
from scipy.spatial import ConvexHull
rows = pickle.load(open('/tmp/rotate_faces.pkl','rb'))
def wrap(a, p=np.pi): return (a + p/2) % p - p/2
def pca(pts):
    c = pts.mean(0); _, v = np.linalg.eigh(np.cov((pts-c).T)); ax = v[:, -1]; return np.arctan2(ax[1], ax[0]) % np.pi
def minrect(pts):
    hull = pts[ConvexHull(pts).vertices]
    best = None
    for k in range(len(hull)):
        e = hull[(k+1) % len(hull)] - hull[k]; a = np.arctan2(e[1], e[0])
        R = np.array([[np.cos(a), np.sin(a)], [-np.sin(a), np.cos(a)]])
        q = hull @ R.T; w, h = np.ptp(q[:, 0]), np.ptp(q[:, 1]); area = w*h
        if best is None or area < best[0]:
            best = (area, a if w >= h else a + np.pi/2)
    return best[1] % np.pi
def edges(pts):
    # refine PCA: fit lines to both long edges (extreme points per bin across the axis), take the edge with more support
    a = pca(pts); ax = np.array([np.cos(a), np.sin(a)]); n = np.array([-ax[1], ax[0]])
    u, v = (pts - pts.mean(0)) @ ax, (pts - pts.mean(0)) @ n
    bins = np.round(u / 0.01)
    lo, hi = [], []
    for b in np.unique(bins):
        m = bins == b
        if m.sum() < 2: continue
        lo.append((u[m].mean(), v[m].min())); hi.append((u[m].mean(), v[m].max()))
    best = []
    for e in (np.array(lo), np.array(hi)):
        if len(e) < 4: continue
        # robust slope: median of pairwise slopes (Theil-Sen)
        i, j = np.triu_indices(len(e), 1)
        du = e[j, 0] - e[i, 0]; ok = np.abs(du) > 0.03
        s = np.median((e[j, 1] - e[i, 1])[ok] / du[ok]) if ok.any() else 0.0
        best.append(s)
    if not best: return a
    s = np.median(best) if len(best) == 1 else sorted(best, key=abs)[0]
    return (a + np.arctan(s)) % np.pi
for name, f in (("pca", pca), ("minrect", minrect), ("edges", edges)):
    errs, errs_part = [], []
    for r in rows:
        if len(r['points']) < 20: continue
        e = abs(np.degrees(wrap(f(r['points']) - r['yaw'])))
        errs.append(e)
        if len(r['points']) < 0.85 * max(len(q['points']) for q in rows if q['seed'] == r['seed']): errs_part.append(e)
    errs, errs_part = np.array(errs), np.array(errs_part)
    print(name, len(errs), "all: mean %.2f p90 %.2f max %.1f" % (errs.mean(), np.percentile(errs, 90), errs.max()),
          "| partial", len(errs_part), "mean %.2f p90 %.2f >3deg %d" % (errs_part.mean(), np.percentile(errs_part, 90), (errs_part > 3).sum()))
import cv2
def cvrect(pts):
    (cx, cy), (w, h), ang = cv2.minAreaRect(pts.astype(np.float32))
    a = np.radians(ang) if w >= h else np.radians(ang) + np.pi / 2
    return a % np.pi
errs = np.array([abs(np.degrees(wrap(cvrect(r['points']) - r['yaw']))) for r in rows if len(r['points']) >= 20])
d = np.array([abs(np.degrees(wrap(cvrect(r['points']) - minrect(r['points'])))) for r in rows if len(r['points']) >= 20])
print("cv2", errs.mean(), np.percentile(errs, 90), errs.max(), "vs minrect max diff", d.max())
full = [r for r in rows if len(r['points']) >= 0.85 * max(len(q['points']) for q in rows if q['seed'] == r['seed'])]
m = np.array([np.linalg.norm(r['points'].mean(0) - r['centre']) for r in full])
c = np.array([np.linalg.norm(np.array(cv2.minAreaRect(r['points'].astype(np.float32))[0]) - r['centre']) for r in full])
print("whole frames", len(full), "centre mean-of-points %.2f cm, rect %.2f cm" % (100*m.mean(), 100*c.mean()))
