"""Off-screen RGB-D rendering of a MuJoCo camera in one pass (colour and depth together).

One ``mjr_render`` fills both the colour and the depth buffer; both are read back in one call
and the reversed-Z depth buffer is turned into metric depth along the optical axis. This is
half the cost of two ``mujoco.Renderer`` passes.
"""

from __future__ import annotations

import mujoco
import numpy as np

from simn_sim.env.gl import gl_error_hint


class OffscreenCamera:
    """Renders a fixed camera of ``model`` at ``width`` x ``height``.

    ``hidden_groups``: geom groups not drawn (the robot's own body for its camera).
    """

    def __init__(
        self,
        model: mujoco.MjModel,
        camera_id: int,
        width: int,
        height: int,
        hidden_groups: tuple[int, ...] = (),
        max_geom: int = 4000,
    ) -> None:
        if width > model.vis.global_.offwidth or height > model.vis.global_.offheight:
            raise ValueError(
                f"render size {width}x{height} exceeds the offscreen buffer "
                f"{model.vis.global_.offwidth}x{model.vis.global_.offheight}"
            )
        self.model = model
        self.width, self.height = int(width), int(height)
        try:
            from mujoco import gl_context

            self._gl = gl_context.GLContext(self.width, self.height)
            self._gl.make_current()
            self._con = mujoco.MjrContext(model, mujoco.mjtFontScale.mjFONTSCALE_150.value)
        except Exception as e:  # noqa: BLE001 - any GL failure gets one clear message
            raise gl_error_hint(e) from e
        mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN.value, self._con)
        self._con.readDepthMap = mujoco.mjtDepthMap.mjDEPTH_ZEROFAR
        self._scn = mujoco.MjvScene(model, maxgeom=max_geom)
        self._opt = mujoco.MjvOption()
        for g in hidden_groups:
            self._opt.geomgroup[g] = 0
        self._cam = mujoco.MjvCamera()
        self._cam.type = mujoco.mjtCamera.mjCAMERA_FIXED
        self._cam.fixedcamid = camera_id
        self._rect = mujoco.MjrRect(0, 0, self.width, self.height)
        self._rgb = np.empty((self.height, self.width, 3), np.uint8)
        self._zbuf = np.empty((self.height, self.width), np.float32)
        extent = model.stat.extent
        near = np.float32(model.vis.map.znear * extent)
        far = np.float32(model.vis.map.zfar * extent)
        c = -(far + near) / (far - near)
        d = -(np.float32(2) * far * near) / (far - near)
        self._c = float(np.float32(-0.5) * c - np.float32(0.5))
        self._d = float(np.float32(-0.5) * d)

    def _draw(self, data: mujoco.MjData, segmentation: bool = False) -> None:
        self._gl.make_current()
        mujoco.mjv_updateScene(
            self.model,
            data,
            self._opt,
            None,
            self._cam,
            mujoco.mjtCatBit.mjCAT_ALL.value,
            self._scn,
        )
        self._scn.flags[mujoco.mjtRndFlag.mjRND_SEGMENT] = segmentation
        self._scn.flags[mujoco.mjtRndFlag.mjRND_IDCOLOR] = segmentation
        mujoco.mjr_render(self._rect, self._scn, self._con)

    def render_rgbd(self, data: mujoco.MjData) -> tuple[np.ndarray, np.ndarray]:
        """(H, W, 3) uint8 RGB and (H, W) float32 metric depth along the optical axis."""
        self._draw(data)
        mujoco.mjr_readPixels(self._rgb, self._zbuf, self._rect, self._con)
        depth = (self._d / (self._zbuf.astype(np.float64) + self._c)).astype(np.float32)
        return np.flipud(self._rgb).copy(), np.flipud(depth).copy()

    def render_rgb(self, data: mujoco.MjData) -> np.ndarray:
        self._draw(data)
        mujoco.mjr_readPixels(self._rgb, None, self._rect, self._con)
        return np.flipud(self._rgb).copy()

    def render_segmentation(self, data: mujoco.MjData) -> np.ndarray:
        """(H, W) int32 geom id per pixel (-1 for background)."""
        self._draw(data, segmentation=True)
        mujoco.mjr_readPixels(self._rgb, None, self._rect, self._con)
        rgb = np.flipud(self._rgb).astype(np.int32)
        ids = rgb[..., 0] + rgb[..., 1] * 256 + rgb[..., 2] * 65536 - 1
        # segid -> geom id via the scene's geom list
        out = np.full(ids.shape, -1, np.int32)
        ngeom = self._scn.ngeom
        objid = np.array([self._scn.geoms[i].objid for i in range(ngeom)], np.int32)
        objtype = np.array([self._scn.geoms[i].objtype for i in range(ngeom)], np.int32)
        ok = (ids >= 0) & (ids < ngeom)
        sel = ids[ok]
        gid = np.where(objtype[sel] == int(mujoco.mjtObj.mjOBJ_GEOM), objid[sel], -1)
        out[ok] = gid
        return out

    def close(self) -> None:
        if getattr(self, "_con", None) is not None:
            self._con.free()
            self._con = None
        if getattr(self, "_gl", None) is not None:
            self._gl.free()
            self._gl = None

    def __del__(self) -> None:  # pragma: no cover - best effort cleanup
        try:
            self.close()
        except Exception:  # noqa: BLE001
            pass
