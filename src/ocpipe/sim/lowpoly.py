"""Robot visuals with decimated meshes, to cut CPU rendering time.

On lavapipe the study's frames are vertex-bound: ~134k of the scene's ~157k triangles are the Panda's visual
meshes, which are far finer than a 128 px camera can resolve. This module writes, once, a copy of a robot's URDF
whose *visual* meshes are decimated (quadric edge collapse, per material part so colours are kept) and makes an
env load its agent from that copy. Collision meshes are referenced by absolute path to the original files (and the
SRDF is copied verbatim), so physics is bit-identical; only what the cameras see changes.

Use:  cls = lowpoly.agent_class(Panda, keep=0.1)          # Panda subclass whose urdf_path is the decimated copy
      class Env(lowpoly.LowPolyAgentMixin, StudyEnv): ...  # env loads its robot through agent_class
      env = Env(..., robot_visual_keep=0.1)
"""

from __future__ import annotations

import functools
import hashlib
import os
import shutil
import tempfile
import xml.etree.ElementTree as ET
from pathlib import Path

# Bump when the output of decimate_visual_mesh changes, so stale caches are not reused.
_VERSION = "3"
# Parts this small (e.g. the 16-triangle status lights on link6) are kept whole: they cost nothing to draw and
# would collapse to nothing.
_MIN_FACES = 64


def default_cache_root() -> Path:
    return Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "ocpipe" / "lowpoly"


def decimate_visual_mesh(src: Path, dst: Path, keep: float) -> tuple[int, int]:
    """Write a copy of the glTF/mesh file ``src`` at ``dst`` with about ``keep`` of its triangles.

    Each geometry (one per material in these files) is decimated on its own, keeping its PBR material and node
    transform. A ``dst`` that is not .glb (an STL, as the wrist camera's) gets one plain mesh in that format: such
    files carry no material, the URDF's <material> colours them, and the loader must see the same kind of file.
    Returns (triangles before, after)."""
    import fast_simplification
    import numpy as np
    import trimesh

    scene = trimesh.load(str(src), force="scene")
    # trimesh names the file's nodes with random suffixes; rebuild the scene with fixed names and file order so the
    # output bytes (and so the cache) are reproducible.
    instances = {}
    for node in scene.graph.nodes_geometry:
        transform, gname = scene.graph[node]
        instances.setdefault(gname, []).append(transform)
    out = trimesh.Scene()
    before = after = 0
    for gname, geom in scene.geometry.items():
        n = len(geom.faces)
        target = max(_MIN_FACES, int(round(n * keep)))
        mesh = geom
        if target < n:
            # The files are flat shaded (three unshared vertices per triangle): weld by position first, or the
            # simplifier sees a soup of disconnected triangles and cannot collapse anything.
            welded = trimesh.Trimesh(geom.vertices, geom.faces, process=False)
            welded.merge_vertices(merge_tex=True, merge_norm=True)
            v, f = fast_simplification.simplify(np.asarray(welded.vertices, dtype=np.float64),
                                                np.asarray(welded.faces, dtype=np.int64), target_count=target)
            # Unweld again so per-vertex normals are the face normals: the same flat shading as the original.
            mesh = trimesh.Trimesh(v, f, process=False)
            mesh.unmerge_vertices()
            if hasattr(geom.visual, "material"):
                mesh.visual = trimesh.visual.TextureVisuals(material=geom.visual.material)
        for j, transform in enumerate(sorted(instances.get(gname, []), key=lambda t: t.tobytes())):
            out.add_geometry(mesh, node_name=f"{gname}#{j}", geom_name=gname, transform=transform)
            before += n
            after += len(mesh.faces)
    dst.parent.mkdir(parents=True, exist_ok=True)
    if dst.suffix.lower() == ".glb":
        dst.write_bytes(trimesh.exchange.gltf.export_glb(out, include_normals=True))
    else:
        plain = trimesh.util.concatenate(out.dump())
        dst.write_bytes(plain.export(file_type=dst.suffix.lower().lstrip(".")))
    return before, after


def _out_suffix(source: str) -> str:
    """glTF sources are rewritten as .glb (materials kept); any other mesh format keeps its own."""
    suffix = Path(source).suffix.lower()
    return ".glb" if suffix in (".glb", ".gltf") else suffix


def _visual_meshes(root: ET.Element):
    return [m for v in root.iter("visual") for m in v.iter("mesh")]


def decimated_urdf(urdf_path: str | os.PathLike, keep: float, cache_root: str | os.PathLike | None = None) -> Path:
    """Path of a copy of ``urdf_path`` whose visual meshes keep about ``keep`` (0..1] of their triangles.

    Built once and cached under ``cache_root``/<hash of code version, keep, URDF and visual mesh bytes>; the build
    is deterministic (same inputs, same files) and written to a temp dir then renamed, so concurrent jobs are safe.
    Collision meshes point (by absolute path) at the originals, and the SRDF is copied, so physics is unchanged."""
    import fast_simplification
    import trimesh

    if not 0 < keep <= 1:
        raise ValueError(f"keep must be in (0, 1], got {keep}")
    urdf_path = Path(urdf_path).resolve()
    src_dir = urdf_path.parent
    root = ET.parse(urdf_path).getroot()
    meshes = _visual_meshes(root)
    sources = sorted({m.get("filename") for m in meshes})
    if any(s.startswith("package://") for s in sources):
        raise NotImplementedError(f"{urdf_path}: package:// mesh paths are not supported")

    h = hashlib.sha256(f"{_VERSION} {keep!r} {_MIN_FACES} {trimesh.__version__} "
                       f"{getattr(fast_simplification, '__version__', '?')}".encode())
    # the copy names the collision meshes by absolute path: a copy built from another install (another clone's
    # venv, since removed) would load a robot without them, so where the originals lie is part of the key
    h.update(str(src_dir).encode())
    h.update(urdf_path.read_bytes())
    for s in sources:
        h.update(s.encode())
        h.update((src_dir / s).read_bytes())
    out_dir = Path(cache_root or default_cache_root()) / f"{urdf_path.stem}-{keep:g}-{h.hexdigest()[:16]}"
    out_urdf = out_dir / urdf_path.name
    if out_urdf.is_file():
        missing = [f for f in _referenced_files(out_urdf) if not Path(f).is_file()]
        if missing:
            raise FileNotFoundError(f"{out_urdf}: the cached robot names {missing[0]}, which no longer exists "
                                    f"({len(missing)} such files); delete {out_dir} to rebuild it")
        return out_urdf

    out_dir.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=".build-", dir=out_dir.parent))
    try:
        # One decimated file per distinct source mesh (finger.glb is shared by both fingers).
        renamed = {s: f"visual/{i:02d}_{Path(s).stem}{_out_suffix(s)}" for i, s in enumerate(sources)}
        for s, d in renamed.items():
            decimate_visual_mesh(src_dir / s, tmp / d, keep)
        for m in meshes:
            m.set("filename", renamed[m.get("filename")])
        # Everything else (collision meshes, textures) stays where it was: absolute paths to the originals.
        for tag in root.iter():
            f = tag.get("filename")
            if f is not None and f not in renamed.values() and not os.path.isabs(f):
                tag.set("filename", str(src_dir / f))
        ET.ElementTree(root).write(tmp / urdf_path.name, encoding="utf-8", xml_declaration=True)
        srdf = urdf_path.with_suffix(".srdf")  # SAPIEN's loader reads <name>.srdf beside the URDF (self-collisions)
        if srdf.is_file():
            shutil.copyfile(srdf, tmp / srdf.name)
        try:
            os.rename(tmp, out_dir)
        except OSError:  # another process finished first: use its copy
            if not out_urdf.is_file():
                raise
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return out_urdf


def _referenced_files(urdf: Path) -> list[str]:
    """Every file a URDF names, as absolute paths (relative ones are beside it)."""
    names = (t.get("filename") for t in ET.parse(urdf).getroot().iter() if t.get("filename") is not None)
    return [n if os.path.isabs(n) else str(urdf.parent / n) for n in names]


@functools.cache
def agent_class(agent_cls: type, keep: float, cache_root: str | None = None) -> type:
    """Subclass of a ManiSkill agent class (e.g. Panda) that loads its decimated-visual URDF.

    Same uid, controllers and keyframes; only ``urdf_path`` differs."""
    path = decimated_urdf(agent_cls.urdf_path, keep, cache_root)
    return type(f"LowPoly{agent_cls.__name__}", (agent_cls,), {"urdf_path": str(path), "__module__": __name__})


def coarsen_ground(actor, cells: int = 2) -> None:
    """Redraw a ManiSkill ``build_ground`` floor (a 100 x 100 grid of 1 m squares: 20k triangles) with a
    ``cells`` x ``cells`` grid of the same extent. Its UVs are an affine function of x, y, so they are fitted on the
    original vertices and evaluated on the coarse ones: the same texture, without the 20k vertices.

    Only the render shape changes (same entity, so the same segmentation id); the collision plane is untouched."""
    import numpy as np
    import sapien

    for obj in actor._objs:
        old = obj.find_component_by_type(sapien.render.RenderBodyComponent)
        (shape,) = old.render_shapes
        (part,) = shape.parts
        v, uv = np.asarray(part.vertices, dtype=np.float64), np.asarray(part.get_vertex_uv(), dtype=np.float64)
        coef, *_ = np.linalg.lstsq(np.c_[v[:, :2], np.ones(len(v))], uv, rcond=None)  # uv = [x y 1] @ coef
        (x0, y0), (x1, y1), z = v[:, :2].min(0), v[:, :2].max(0), v[0, 2]
        xs, ys = np.meshgrid(np.linspace(x0, x1, cells + 1), np.linspace(y0, y1, cells + 1), indexing="ij")
        verts = np.c_[xs.ravel(), ys.ravel(), np.full(xs.size, z)]
        idx = np.arange(verts.shape[0]).reshape(cells + 1, cells + 1)
        a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
        tris = np.r_[np.c_[a, b, c], np.c_[a, c, d]]
        # keep the original winding (which side faces up)
        n_old = np.cross(*(v[part.triangles[0][1:]] - v[part.triangles[0][0]]))
        n_new = np.cross(*(verts[tris[0][1:]] - verts[tris[0][0]]))
        if np.sign(n_old[2]) != np.sign(n_new[2]):
            tris = tris[:, ::-1]
        new_shape = sapien.render.RenderShapeTriangleMesh(
            vertices=verts.astype(np.float32), triangles=tris.astype(np.uint32),
            normals=np.tile(np.float32([0, 0, 1]), (len(verts), 1)),
            uvs=(np.c_[verts[:, :2], np.ones(len(verts))] @ coef).astype(np.float32), material=part.material)
        new_shape.local_pose = shape.local_pose
        comp = sapien.render.RenderBodyComponent()
        comp.attach(new_shape)
        obj.remove_component(old)
        obj.add_component(comp)


class LowPolyAgentMixin:
    """Env mixin (put before the ManiSkill env class): ``robot_visual_keep=k`` loads the robot with about k of its
    visual triangles; None loads the original files (1.0 loads an undecimated re-export: a check of the pipeline).

    ManiSkill's BaseEnv._load_agent accepts an agent class in place of a uid in ``robot_uids``, but tasks also read
    ``robot_uids`` as a string (PickCube picks its per-robot settings with it), so the class is swapped in only for
    the duration of _load_agent."""

    def __init__(self, *args, robot_visual_keep: float | None = None, ground_cells: int | None = None, **kwargs):
        self._robot_visual_keep = robot_visual_keep
        self._ground_cells = ground_cells
        super().__init__(*args, **kwargs)

    def _load_scene(self, options):
        super()._load_scene(options)
        # the table tasks keep their TableSceneBuilder as table_scene; its ground has the 20k-triangle floor
        ground = getattr(getattr(self, "table_scene", None), "ground", None)
        if self._ground_cells is not None and ground is not None and self.scene.can_render():
            coarsen_ground(ground, self._ground_cells)

    def _load_agent(self, options, *args, **kwargs):
        keep = self._robot_visual_keep
        if keep is None or not isinstance(self.robot_uids, str):
            return super()._load_agent(options, *args, **kwargs)
        from mani_skill.agents.registration import REGISTERED_AGENTS

        uid = self.robot_uids
        self.robot_uids = agent_class(REGISTERED_AGENTS[uid].agent_cls, float(keep))
        try:
            return super()._load_agent(options, *args, **kwargs)
        finally:
            self.robot_uids = uid
