#!/usr/bin/env python3
"""Writes ground_blocks.obj: a 140 m ground plane (a 22 x 22 grid of squares,
968 triangles) with 12 blocks (12 triangles each): 1,112 triangles, like
HELIOS++'s toy-blocks scene exported to one OBJ (bench/cluster_bench.sh).

`make_ground_blocks.py GRID OUT.obj` writes the same scene with a GRID x GRID
ground (GRID 707: about 10^6 triangles, for the beam-count benchmark)."""

import sys

vertices, faces = [], []


def quad(a, b, c, d):
    base = len(vertices)
    vertices.extend([a, b, c, d])
    faces.append((base + 1, base + 2, base + 3))
    faces.append((base + 1, base + 3, base + 4))


n, half = (int(sys.argv[1]) if len(sys.argv) > 1 else 22), 70.0
step = 2 * half / n
for i in range(n):
    for j in range(n):
        x0, y0 = -half + i * step, -half + j * step
        quad((x0, y0, 0), (x0 + step, y0, 0), (x0 + step, y0 + step, 0), (x0, y0 + step, 0))

blocks = [(8 + 6 * (k % 4), -12 + 8 * (k // 4), 1.0 + 0.7 * k) for k in range(12)]
for (cx, cy, h) in blocks:
    x0, x1, y0, y1 = cx - 1.5, cx + 1.5, cy - 1.5, cy + 1.5
    quad((x0, y0, 0), (x0, y1, 0), (x0, y1, h), (x0, y0, h))  # -x face
    quad((x1, y0, 0), (x1, y0, h), (x1, y1, h), (x1, y1, 0))  # +x face
    quad((x0, y0, 0), (x0, y0, h), (x1, y0, h), (x1, y0, 0))  # -y face
    quad((x0, y1, 0), (x1, y1, 0), (x1, y1, h), (x0, y1, h))  # +y face
    quad((x0, y0, h), (x0, y1, h), (x1, y1, h), (x1, y0, h))  # top
    quad((x0, y0, 0), (x1, y0, 0), (x1, y1, 0), (x0, y1, 0))  # bottom

with open(sys.argv[2] if len(sys.argv) > 2 else "ground_blocks.obj", "w") as f:
    f.write(f"# {len(faces)} triangles: ground plane and blocks (make_ground_blocks.py)\n")
    for v in vertices:
        f.write("v {:g} {:g} {:g}\n".format(*v))
    for t in faces:
        f.write("f {} {} {}\n".format(*t))
