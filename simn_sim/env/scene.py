"""Build the MuJoCo model of an office layout plus the mobile base with ``mujoco.MjSpec``.

The robot comes from its own MJCF (``assets/robot.xml``); the office (floor, walls, furniture,
lights, an overview camera) is added to the same spec from a :class:`~simn_sim.env.layout.Layout`.
Semantic classes of geoms are kept in :data:`SEMANTIC_IDS` so that the segmentation render can
be mapped to floor / obstacle / robot.
"""

from __future__ import annotations

import dataclasses
import math

import mujoco
import numpy as np

from simn_sim.env.layout import Layout
from simn_sim.paths import assets_dir

ROBOT_RADIUS = 0.25
PERSON_RADIUS = 0.22  # the people's capsules (the dynamic office)
ROBOT_Z_BAND = (0.03, 0.95)  # vertical extent of the robot hull (m): footprints use this band
ROBOT_GROUP = 3  # geom group of the robot's own geoms (hidden from its camera)
PEOPLE_GROUP = 4

SEMANTIC_IDS = {"unknown": 0, "floor": 1, "obstacle": 2, "robot": 3, "person": 4}


@dataclasses.dataclass
class SceneModel:
    model: mujoco.MjModel
    hull_geom: int
    camera_id: int
    overview_camera_id: int
    qpos_adr: np.ndarray  # x, y, yaw qpos addresses
    dof_adr: np.ndarray
    geom_semantic: np.ndarray  # (ngeom,) semantic id per geom
    people_mocap: list[int]  # mocap ids of people (dynamic office)


def build_scene(
    layout: Layout,
    width: int = 640,
    height: int = 480,
    n_people: int = 0,
) -> SceneModel:
    """Compile the office ``layout`` with the robot; the offscreen buffer fits ``width``x``height``."""
    spec = mujoco.MjSpec.from_file(str(assets_dir() / "robot.xml"))
    spec.modelname = f"simn_office_{layout.layout_seed}"
    W, H = layout.size
    spec.visual.global_.offwidth = max(int(width), 640)
    spec.visual.global_.offheight = max(int(height), 480)
    spec.visual.map.znear = 0.005  # relative to the model extent
    spec.visual.map.zfar = 4.0
    spec.stat.extent = float(max(W, H))
    spec.stat.center = [W / 2, H / 2, 1.0]
    spec.visual.headlight.ambient = [0.35, 0.35, 0.35]
    spec.visual.headlight.diffuse = [0.4, 0.4, 0.4]
    spec.visual.quality.shadowsize = 0
    # no MSAA: a multisampled depth buffer resolves to biased depth (mm errors), and it costs time
    spec.visual.quality.offsamples = 0

    floor_tex = spec.add_texture(
        name="floor_tex",
        type=mujoco.mjtTexture.mjTEXTURE_2D,
        builtin=mujoco.mjtBuiltin.mjBUILTIN_CHECKER,
        rgb1=[0.62, 0.60, 0.55],
        rgb2=[0.48, 0.46, 0.42],
        width=256,
        height=256,
        mark=mujoco.mjtMark.mjMARK_EDGE,
        markrgb=[0.3, 0.3, 0.3],
    )
    floor_mat = spec.add_material(name="floor_mat", texrepeat=[W / 1.2, H / 1.2], reflectance=0.0)
    floor_mat.textures[mujoco.mjtTextureRole.mjTEXROLE_RGB] = floor_tex.name
    wall_tex = spec.add_texture(
        name="wall_tex",
        type=mujoco.mjtTexture.mjTEXTURE_2D,
        builtin=mujoco.mjtBuiltin.mjBUILTIN_FLAT,
        rgb1=[0.9, 0.9, 0.9],
        rgb2=[0.7, 0.7, 0.7],
        width=128,
        height=128,
        mark=mujoco.mjtMark.mjMARK_RANDOM,
        markrgb=[0.55, 0.55, 0.55],
        random=0.03,
    )
    wall_mat = spec.add_material(name="wall_mat", texrepeat=[2, 2], texuniform=True)
    wall_mat.textures[mujoco.mjtTextureRole.mjTEXROLE_RGB] = wall_tex.name

    wb = spec.worldbody
    wb.add_geom(
        name="floor",
        type=mujoco.mjtGeom.mjGEOM_PLANE,
        size=[W / 2, H / 2, 0.1],
        pos=[W / 2, H / 2, 0.0],
        material="floor_mat",
        contype=0,
        conaffinity=0,
    )
    for b in layout.boxes:
        g = wb.add_geom(
            name=b.name,
            type=mujoco.mjtGeom.mjGEOM_BOX,
            size=list(b.half),
            pos=list(b.center),
            quat=[math.cos(b.yaw / 2), 0.0, 0.0, math.sin(b.yaw / 2)],
            rgba=list(b.rgba),
            contype=1,
            conaffinity=2,
        )
        if b.kind == "wall":
            g.material = "wall_mat"
    # lights: a grid of soft directional-ish spot lights from the ceiling
    for i, x in enumerate(np.linspace(W * 0.2, W * 0.8, 3)):
        for j, y in enumerate(np.linspace(H * 0.25, H * 0.75, 2)):
            wb.add_light(
                name=f"light_{i}{j}",
                pos=[float(x), float(y), 6.0],
                dir=[0.0, 0.0, -1.0],
                diffuse=[0.28, 0.28, 0.27],
                specular=[0.05, 0.05, 0.05],
                castshadow=False,
                cutoff=80.0,
                attenuation=[1.0, 0.0, 0.0],
            )
    # an overview camera for people (render_mode rgb_array)
    fovy = 45.0
    dist = 0.5 * max(H, W * height / width) / math.tan(math.radians(fovy / 2)) * 1.05
    wb.add_camera(name="overview", pos=[W / 2, H / 2, dist], fovy=fovy)
    people_bodies = []
    for k in range(n_people):
        body = wb.add_body(name=f"person{k}", mocap=True, pos=[-10.0 - k, -10.0, 0.0])
        body.add_geom(
            name=f"person{k}_body",
            type=mujoco.mjtGeom.mjGEOM_CAPSULE,
            size=[PERSON_RADIUS, 0.6],
            pos=[0.0, 0.0, 0.85],
            rgba=[0.85, 0.65, 0.55, 1.0],
            contype=1,
            conaffinity=2,
        )
        people_bodies.append(body)

    model = spec.compile()
    sem = np.full(model.ngeom, SEMANTIC_IDS["obstacle"], dtype=np.int32)
    sem[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, "floor")] = SEMANTIC_IDS["floor"]
    robot_body = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, "base")
    sem[model.geom_bodyid == robot_body] = SEMANTIC_IDS["robot"]
    people_mocap = []
    for k in range(n_people):
        bid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, f"person{k}")
        sem[model.geom_bodyid == bid] = SEMANTIC_IDS["person"]
        people_mocap.append(int(model.body_mocapid[bid]))
    joints = [
        mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, n)
        for n in ("base_x", "base_y", "base_yaw")
    ]
    return SceneModel(
        model=model,
        hull_geom=mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, "base_hull"),
        camera_id=mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, "rgbd"),
        overview_camera_id=mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, "overview"),
        qpos_adr=model.jnt_qposadr[joints].copy(),
        dof_adr=model.jnt_dofadr[joints].copy(),
        geom_semantic=sem,
        people_mocap=people_mocap,
    )
