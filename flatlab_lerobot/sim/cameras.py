"""Offscreen cameras: RGB, metric depth, segmentation, and point clouds from depth.

One :class:`CameraRig` owns one lazily created ``mujoco.Renderer`` (all cameras share a size) and
caches each camera's frame per ``data`` state: :meth:`CameraRig.capture` renders a camera once in
normal mode (reading RGB *and* the depth buffer from that same pass) and, only when asked, once more
in segmentation mode (which also yields depth, so a cloud-only observation costs one pass).  Call :meth:`CameraRig.close` when done (the GL context is not freed otherwise).

Back-projection (verified: the table plane comes back flat at its true height, see
``tests/test_cameras.py``)::

    f = (H/2) / tan(fovy/2)
    x = (u + 0.5 - W/2) z / f ;  y = -(v + 0.5 - H/2) z / f ;  p_cam = (x, y, -z)
    p_world = cam_xmat @ p_cam + cam_xpos

where (u, v) is the pixel column/row (row 0 at the top of the returned image) and z the metric
depth along the optical axis.
"""

from __future__ import annotations

import contextlib
from dataclasses import dataclass

import mujoco
import numpy as np

GEOM = int(mujoco.mjtObj.mjOBJ_GEOM)
FLEX = int(mujoco.mjtObj.mjOBJ_FLEX)


@dataclass
class Frame:
    """One camera's images for one physics state."""

    rgb: np.ndarray | None  # (H, W, 3) uint8 (None if only a segmentation pass was needed)
    depth: np.ndarray  # (H, W) float32, metres along the optical axis
    seg: np.ndarray | None = None  # (H, W, 2) int32: (object id, mjtObj type); -1 for background


class CameraRig:
    """Renders the named fixed cameras of ``model`` at ``width`` x ``height``."""

    def __init__(self, model: mujoco.MjModel, width: int = 96, height: int = 96, camera_names=("front",)):
        self.model = model
        self.width, self.height = int(width), int(height)
        self.camera_names = tuple(camera_names)
        for c in self.camera_names:
            if mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, c) < 0:
                raise ValueError(f"camera {c!r} not in the model")
        self._renderers: dict[tuple[int, int], mujoco.Renderer] = {}
        self._cache: dict[str, Frame] = {}
        self._cache_key = None
        extent = model.stat.extent
        self.znear = np.float32(model.vis.map.znear * extent)
        self.zfar = np.float32(model.vis.map.zfar * extent)

    # ------------------------------------------------------------------ renderers
    def renderer(self, width: int | None = None, height: int | None = None) -> mujoco.Renderer:
        """The (lazily created) renderer for one image size."""
        key = (int(height or self.height), int(width or self.width))
        r = self._renderers.get(key)
        if r is None:
            r = self._renderers[key] = mujoco.Renderer(self.model, height=key[0], width=key[1])
        return r

    def close(self) -> None:
        for r in self._renderers.values():
            r.close()
        self._renderers.clear()
        self._cache.clear()

    def __del__(self):
        with contextlib.suppress(Exception):  # interpreter shutdown: GL may already be gone
            self.close()

    def invalidate(self) -> None:
        """Forget cached frames (call after the physics state changed)."""
        self._cache.clear()
        self._cache_key = None

    def _key(self, data: mujoco.MjData):
        # time + a cheap fingerprint of the state: frames are reused only within one state
        return (id(data), float(data.time), float(np.sum(data.qpos[: min(8, data.qpos.size)])))

    # ------------------------------------------------------------------ capture
    def capture(self, data: mujoco.MjData, cam: str, segmentation: bool = False, rgb: bool = True) -> Frame:
        """Images of ``cam`` for the current state of ``data``, cached until the state changes.

        RGB and depth come from one normal render pass; segmentation needs a second pass with
        id colours.  With ``rgb=False`` a segmentation request is served by that single pass alone
        (depth is read from it too) and ``Frame.rgb`` is None."""
        key = self._key(data)
        if key != self._cache_key:
            self._cache.clear()
            self._cache_key = key
        fr = self._cache.get(cam)
        if fr is not None and (fr.seg is not None or not segmentation) and (fr.rgb is not None or not rgb):
            return fr
        r = self.renderer()
        r.update_scene(data, cam)
        if fr is None and (rgb or not segmentation):
            fr = Frame(*self._render(r, segment=False))
        elif fr is not None and rgb and fr.rgb is None:
            fr.rgb = self._render(r, segment=False)[0]
        if segmentation and (fr is None or fr.seg is None):
            _, depth, seg = self._render(r, segment=True)
            fr = fr or Frame(None, depth)
            fr.seg = seg
        self._cache[cam] = fr
        return fr

    def _render(self, r: mujoco.Renderer, segment: bool):
        """One ``mjr_render`` + one ``mjr_readPixels`` of colour and depth.  ``segment``: colours
        are geom-id colours, decoded into (object id, object type) -> (rgb None, depth, seg)."""
        ctx, rect, scn = r._mjr_context, r._rect, r.scene  # the public API renders once per buffer
        if ctx is None:
            raise RuntimeError("renderer closed")
        if r._gl_context:
            r._gl_context.make_current()
        rgb = np.empty((self.height, self.width, 3), np.uint8)
        zbuf = np.empty((self.height, self.width), np.float32)
        flags = scn.flags.copy()
        try:
            if segment:
                scn.flags[mujoco.mjtRndFlag.mjRND_SEGMENT] = True
                scn.flags[mujoco.mjtRndFlag.mjRND_IDCOLOR] = True
            mujoco.mjr_render(rect, scn, ctx)
            mujoco.mjr_readPixels(rgb, zbuf, rect, ctx)
        finally:
            np.copyto(scn.flags, flags)
        # Same linearisation as mujoco.Renderer (perspective cameras, mjDEPTH_ZEROFAR).
        zfar, znear = self.zfar, self.znear
        c = np.float32(-0.5) * (-(zfar + znear) / (zfar - znear)) - np.float32(0.5)
        d = np.float32(-0.5) * (-(np.float32(2) * zfar * znear) / (zfar - znear))
        depth = np.ascontiguousarray(np.flipud((d / (zbuf.astype(np.float64) + c)).astype(np.float32)))
        rgb = np.ascontiguousarray(np.flipud(rgb))
        if not segment:
            return rgb, depth, None
        # Decode as mujoco.Renderer does: colour = segid + 1 (0 = background).
        segimg = (
            rgb[..., 0].astype(np.int64) + (rgb[..., 1].astype(np.int64) << 8) + (rgb[..., 2].astype(np.int64) << 16)
        )
        n = scn.ngeom
        lut = np.full((n + 1, 2), -1, np.int32)
        for g in scn.geoms[:n]:
            if g.segid != -1:
                lut[g.segid + 1] = (g.objid, g.objtype)
        return None, depth, lut[np.clip(segimg, 0, n)]

    def rgb(self, data: mujoco.MjData, cam: str) -> np.ndarray:
        return self.capture(data, cam, rgb=True).rgb

    def depth(self, data: mujoco.MjData, cam: str) -> np.ndarray:
        fr = self._cache.get(cam) if self._cache_key == self._key(data) else None
        return fr.depth if fr is not None else self.capture(data, cam, rgb=False, segmentation=True).depth

    def segmentation(self, data: mujoco.MjData, cam: str) -> np.ndarray:
        """(H, W, 2) int32: per pixel (object id, mjtObj type) -- geoms are type mjOBJ_GEOM, the
        cloth is type mjOBJ_FLEX with the flex id; background is (-1, -1)."""
        return self.capture(data, cam, segmentation=True, rgb=False).seg

    def render_rgb(self, data: mujoco.MjData, cam: str, width: int, height: int) -> np.ndarray:
        """An RGB frame of another size (e.g. for videos), not cached."""
        r = self.renderer(width, height)
        r.update_scene(data, cam)
        return r.render()

    # ------------------------------------------------------------------ geometry
    def intrinsics(self, cam: str) -> tuple[float, float, float, float]:
        """(fx, fy, cx, cy) in pixels for the rig's image size (square pixels)."""
        fovy = np.deg2rad(self.model.cam_fovy[self.model.camera(cam).id])
        f = (self.height / 2) / np.tan(fovy / 2)
        return float(f), float(f), self.width / 2 - 0.5, self.height / 2 - 0.5

    def extrinsics(self, data: mujoco.MjData, cam: str) -> tuple[np.ndarray, np.ndarray]:
        """(cam_xpos (3,), cam_xmat (3, 3)): camera-to-world; the camera looks along its -z."""
        i = self.model.camera(cam).id
        return data.cam_xpos[i].copy(), data.cam_xmat[i].reshape(3, 3).copy()

    def depth_to_points(self, depth: np.ndarray, cam: str, data: mujoco.MjData, mask: np.ndarray | None = None):
        """World-frame points (K, 3) of the pixels of ``depth`` (optionally only where ``mask``).
        Pixels at or beyond the far plane (nothing hit) are dropped."""
        H, W = depth.shape
        fovy = np.deg2rad(self.model.cam_fovy[self.model.camera(cam).id])
        f = (H / 2) / np.tan(fovy / 2)
        valid = depth < 0.99 * self.zfar
        if mask is not None:
            valid &= mask
        v, u = np.nonzero(valid)
        z = depth[v, u].astype(np.float64)
        p = np.stack([(u + 0.5 - W / 2) * z / f, -(v + 0.5 - H / 2) * z / f, -z], axis=1)
        pos, R = self.extrinsics(data, cam)
        return p @ R.T + pos

    def object_mask(self, seg: np.ndarray, obj_geoms=(), flex_id: int = -1) -> np.ndarray:
        """Pixels showing the object: one of the rigid object's geoms, or the cloth flex."""
        ids, types = seg[..., 0], seg[..., 1]
        mask = np.zeros(ids.shape, bool)
        if len(obj_geoms):
            mask |= (types == GEOM) & np.isin(ids, np.asarray(obj_geoms))
        if flex_id >= 0:
            mask |= (types == FLEX) & (ids == flex_id)
        return mask

    def scene_points(self, data: mujoco.MjData, cams=None) -> np.ndarray:
        cams = self.camera_names if cams is None else cams
        pts = [self.depth_to_points(self.depth(data, c), c, data) for c in cams]
        return np.concatenate(pts) if pts else np.zeros((0, 3))

    def object_points(self, data: mujoco.MjData, obj_geoms=(), flex_id: int = -1, cams=None) -> np.ndarray:
        cams = self.camera_names if cams is None else cams
        pts = []
        for c in cams:
            fr = self.capture(data, c, segmentation=True, rgb=False)
            pts.append(self.depth_to_points(fr.depth, c, data, self.object_mask(fr.seg, obj_geoms, flex_id)))
        return np.concatenate(pts) if pts else np.zeros((0, 3))


def crop(points: np.ndarray, lo, hi) -> np.ndarray:
    """Points inside the axis-aligned box [lo, hi] (world frame)."""
    lo, hi = np.asarray(lo), np.asarray(hi)
    keep = np.all((points >= lo) & (points <= hi), axis=1)
    return points[keep]


def sample(points: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    """Exactly ``n`` points (float32): a random subset without replacement, or, when there are
    fewer, a random permutation repeated to length ``n``; zeros when there are none.
    Deterministic given the generator's state."""
    k = len(points)
    if k == 0:
        return np.zeros((n, 3), np.float32)
    if k >= n:
        idx = rng.choice(k, n, replace=False)
    else:
        idx = np.resize(rng.permutation(k), n)
    return points[idx].astype(np.float32)
