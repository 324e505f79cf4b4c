"""Wavefront OBJ reading and writing: vertices and (triangulated) faces.

Read: ``v x y z [w]`` (extra numbers, e.g. vertex colours, are ignored), ``f`` with ``i``,
``i/j``, ``i//k`` and ``i/j/k`` references (1-based; negative ones count back from the last vertex
read so far), polygons triangulated as fans ``(0, i, i + 1)``, ``#`` comments and blank lines.
Other statements (``vt``, ``vn``, ``o``, ``g``, ``s``, ``usemtl``, ``mtllib``, ``l``, ...) are
skipped. Anything malformed raises :class:`OBJParseError` with the path and the line number.
"""

from __future__ import annotations

import math
import os
import pathlib

import numpy as np

from .._errors import JaxanimError, check_shape
from ._mesh import Mesh


class OBJParseError(JaxanimError):
    """An OBJ file could not be parsed.

    Attributes:
        path: the file.
        line: 1-based line number of the offending statement (0 when not tied to a line).
        message: what was expected and what was found.
    """

    def __init__(self, path: str, line: int, message: str):
        self.path = str(path)
        self.line = int(line)
        self.message = message
        super().__init__(f"{self.path}:{self.line}: {message}" if self.line > 0 else f"{self.path}: {message}")


def _vertex_ref(tok: str, n_vertices: int, path: str, line: int) -> tuple[int, int]:
    """0-based vertex index of one face reference; also the 1-based index as written (for messages)."""
    head = tok.split("/", 1)[0]
    try:
        i = int(head)
    except ValueError:
        raise OBJParseError(path, line, f"bad face vertex reference {tok!r}: expected an integer index such as "
                                        f"'3', '3/1', '3//2' or '3/1/2'") from None
    if i == 0:
        raise OBJParseError(path, line, f"face vertex index 0 in {tok!r}: OBJ indices start at 1")
    if i < 0:
        j = n_vertices + i
        if j < 0:
            raise OBJParseError(path, line, f"face vertex index {i} points before the first vertex "
                                            f"(only {n_vertices} vertices read so far)")
        return j, i
    return i - 1, i


def read_obj(path: str | os.PathLike, dtype=None) -> Mesh:
    """Read the vertices and faces of an OBJ file (polygons triangulated as fans).

    Args:
        path: the file.
        dtype: the vertices' float dtype (default: the default float, float64 with x64).

    Returns:
        A :class:`Mesh` with ``[V, 3]`` vertices and ``[T, 3]`` int32 0-based faces.

    Raises:
        OBJParseError: (a :class:`~jaxanim.JaxanimError`) naming the path and the line: a ``v`` with
            fewer than 3 numbers or a non-finite one, a face with fewer than 3 vertices or a bad
            reference, a face pointing past the file's vertices; also an unreadable file or one
            without vertices.
    """
    path_s = str(path)
    try:
        text = pathlib.Path(path).read_text(encoding="utf-8-sig", errors="replace")
    except OSError as exc:
        raise OBJParseError(path_s, 0, f"cannot read it: {exc.strerror or exc}") from None
    verts: list[tuple[float, float, float]] = []
    faces: list[tuple[int, int, int]] = []
    face_lines: list[int] = []
    face_written: list[tuple[int, ...]] = []
    for lineno, raw in enumerate(text.splitlines(), start=1):
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        parts = line.split()
        key = parts[0]
        if key == "v":
            if len(parts) < 4:
                raise OBJParseError(path_s, lineno, f"a vertex needs 3 coordinates 'v x y z', got {line!r}")
            try:
                xyz = tuple(float(t) for t in parts[1:4])
            except ValueError:
                raise OBJParseError(path_s, lineno, f"a vertex needs 3 numbers 'v x y z', got {line!r}") from None
            if not all(math.isfinite(c) for c in xyz):
                raise OBJParseError(path_s, lineno, f"a vertex coordinate is not finite: {line!r}")
            verts.append(xyz)
        elif key == "f":
            refs = parts[1:]
            if len(refs) < 3:
                raise OBJParseError(path_s, lineno, f"a face needs at least 3 vertices, got {len(refs)}: {line!r}")
            idx = [_vertex_ref(t, len(verts), path_s, lineno) for t in refs]
            zero = [i for i, _ in idx]
            written = tuple(w for _, w in idx)
            for i in range(1, len(zero) - 1):  # a fan around the first vertex
                faces.append((zero[0], zero[i], zero[i + 1]))
                face_lines.append(lineno)
                face_written.append(written)
    if not verts:
        raise OBJParseError(path_s, 0, "no vertices ('v x y z' lines) in the file")
    F = np.asarray(faces, np.int64).reshape(-1, 3)
    if F.size:
        bad = np.nonzero((F >= len(verts)).any(axis=1))[0]
        if bad.size:
            t = int(bad[0])
            raise OBJParseError(path_s, face_lines[t],
                                f"face {list(face_written[t])} points past the vertices: the file has {len(verts)} "
                                f"vertices (valid indices 1 to {len(verts)}, or -1 to -{len(verts)})")
    V = np.asarray(verts, np.float64)
    return Mesh(V if dtype is None else V.astype(dtype), F.astype(np.int32))


def _fmt(dtype) -> str:
    return "%.9g" if np.dtype(dtype).itemsize <= 4 else "%.17g"


def write_obj(path: str | os.PathLike, mesh_or_vertices, faces=None, *, comment: str | None = None) -> None:
    """Write vertices and triangles as an OBJ file (1-based ``f a b c`` lines).

    Coordinates are written with enough digits to read back exactly (9 significant digits for
    float32, 17 for float64).

    Args:
        path: the file (overwritten).
        mesh_or_vertices: a :class:`Mesh`, or ``[V, 3]`` vertices.
        faces: ``[T, 3]`` 0-based faces with vertices (ignored for a Mesh, which has its own);
            ``None``: no faces (a point cloud).
        comment: an optional first-line comment (``# comment``).

    Raises:
        JaxanimError: on a wrong shape or a face index outside ``[0, V)``.
        OSError: if the file cannot be written.
    """
    if isinstance(mesh_or_vertices, Mesh):
        mesh = mesh_or_vertices
    else:
        check_shape("vertices", mesh_or_vertices, (None, 3), what="(V, 3)")
        mesh = Mesh(mesh_or_vertices, faces)
    V = np.asarray(mesh.vertices)
    F = np.asarray(mesh.faces, np.int64) + 1
    lines = [f"# {comment}"] if comment else []
    lines.append(f"# {V.shape[0]} vertices, {F.shape[0]} triangles")
    fmt = _fmt(V.dtype)
    body = []
    if V.size:
        line = "v " + " ".join([fmt] * 3)
        body.append("\n".join(line % tuple(row) for row in V.tolist()))
    if F.size:
        body.append("\n".join(f"f {a} {b} {c}" for a, b, c in F.tolist()))
    with open(path, "w", encoding="utf-8") as fh:
        fh.write("\n".join(lines + body) + "\n")
