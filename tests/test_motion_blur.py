"""Motion blur of the camera and of meshes (thesis 2.5.7, 2.5.9) in ``distributed``,
against references by construction.

Mitsuba 3 (3.9) cannot render these: its shapes and sensors have no motion (the
sensor's shutter times are generated but no plugin uses them), so the reference of
each case is the exact time-and-pixel integral of a scene whose radiance is known in
closed form: a black square (reflectance 0) in front of an emitting background of
radiance 1, seen by a pinhole camera with a box filter.  A pixel's value is then
1 − (the fraction of pixel area × shutter time in which its rays meet the square),
integrated here by a midpoint rule over 24×24 film positions per pixel and 192 times
(the camera's eye rays as :class:`core.scene.Camera` defines them, the square's and
camera's pose from the closed-form rigid motion).  Checked by the per-pixel Z-test
(variance: that of a mean of 0/1 samples); negative controls: the still scene and the motion at half the speed fail it.
"""

from pathlib import Path

import numpy as np
import pytest

from core.loader import load_scene
from gibench import registry
from reports.metrics import z_test

DIST = registry.get("distributed")
D_SQUARE, D_BACK, HALF = 3.0, 6.0, 0.45          # square at z = −3 (half side 0.45), wall at z = −6

SCENE = """<scene version="3.0.0">
    <sensor type="perspective">
        <float name="fov" value="40"/>
        <float name="shutter_open" value="0"/>
        <float name="shutter_close" value="1"/>
        {camera}
        <transform name="to_world"><lookat origin="0, 0, 0" target="0, 0, -1" up="0, 1, 0"/></transform>
        <film type="hdrfilm"><integer name="width" value="16"/><integer name="height" value="16"/>
            <rfilter type="box"/></film>
    </sensor>
    <shape type="rectangle">
        <transform name="to_world"><scale value="10"/><translate z="-{back}"/></transform>
        <bsdf type="diffuse"><rgb name="reflectance" value="0"/></bsdf>
        <emitter type="area"><rgb name="radiance" value="1"/></emitter>
    </shape>
    <shape type="rectangle">
        <transform name="to_world"><scale value="{half}"/><translate z="-{square}"/></transform>
        <bsdf type="diffuse"><rgb name="reflectance" value="0"/></bsdf>
        {mesh}
    </shape>
</scene>"""


def _vec(name, v):
    return f'<vector name="{name}" value="{v[0]}, {v[1]}, {v[2]}"/>'


def _scene(tmp_path, cam_v=None, cam_w=None, mesh_v=None, mesh_w=None):
    cam = "".join(_vec(n, v) for n, v in (("gibench_velocity", cam_v),
                                          ("gibench_angular_velocity", cam_w)) if v is not None)
    mesh = "".join(_vec(n, v) for n, v in (("gibench_velocity", mesh_v),
                                           ("gibench_angular_velocity", mesh_w)) if v is not None)
    p = tmp_path / "motion.xml"
    p.write_text(SCENE.format(camera=cam, mesh=mesh, back=D_BACK, square=D_SQUARE, half=HALF))
    return load_scene(p)


def _rot(w, t, v):
    """Rows of ``v`` (n, 3) turned by the rotation vector w·t (Rodrigues)."""
    w = np.asarray(w, dtype=np.float64)
    th = np.linalg.norm(w) * t
    if th == 0.0:
        return v
    k = w / np.linalg.norm(w)
    return v * np.cos(th) + np.cross(k, v) * np.sin(th) + np.outer(v @ k, k) * (1 - np.cos(th))


def exact_image(camera, cam_v=None, cam_w=None, mesh_v=None, mesh_w=None, *, sub=24, times=192):
    """1 − the fraction of each pixel × the shutter [0, 1] whose pinhole rays meet the
    square (midpoint rule over ``sub``² film positions and ``times`` times)."""
    W, H = camera.film.width, camera.film.height
    tx = camera.tan_half_fov_x
    f = (np.arange(sub) + 0.5) / sub
    fx = (np.arange(W)[:, None] + f[None, :]).ravel()          # film x of every sub-column
    fy = (np.arange(H)[:, None] + f[None, :]).ravel()
    u, v = np.meshgrid(fx / W, fy / H)
    d_cam = np.stack([(1 - 2 * u) * tx, (1 - 2 * v) * tx / camera.film.aspect, np.ones_like(u)], -1)
    d0 = d_cam.reshape(-1, 3) @ camera.to_world[:3, :3].T
    o0 = camera.origin
    pivot = np.array([0.0, 0.0, -D_SQUARE])
    hit = np.zeros(len(d0))
    zero = np.zeros(3)
    for t in (np.arange(times) + 0.5) / times:
        o = o0 + t * np.asarray(cam_v if cam_v is not None else zero)
        d = _rot(cam_w if cam_w is not None else zero, t, d0)
        q = o + d * ((-D_SQUARE - o[2]) / d[:, 2])[:, None]    # on the square's plane
        q = _rot(mesh_w if mesh_w is not None else zero, -t,
                 q - pivot - t * np.asarray(mesh_v if mesh_v is not None else zero))
        hit += (np.abs(q[:, 0]) <= HALF) & (np.abs(q[:, 1]) <= HALF)
    cover = (hit / times).reshape(H, sub, W, sub).mean(axis=(1, 3))
    return np.repeat((1.0 - cover)[:, :, None], 3, axis=2)


CASES = {
    "camera translation": dict(cam_v=(0.8, 0.0, 0.0)),
    "camera rotation": dict(cam_w=(0.0, 0.25, 0.0)),
    "mesh translation": dict(mesh_v=(0.0, 0.7, 0.0)),
    "mesh rotation": dict(mesh_w=(0.0, 0.0, 1.2)),
    "mesh translation and rotation": dict(mesh_v=(0.5, 0.0, 0.0), mesh_w=(0.0, 0.0, -1.5)),
}


SPP = 64


def _ztest(expected, res):
    """Z-test of the render against ``expected`` with the variance of a mean of SPP
    radiance samples that are each 0 or 1 with probability p = ``expected``:
    p(1 − p)/SPP, an upper bound for jittered samples (stratification only lowers
    it).  The render's own sample variance is not used: a pixel that sees the square
    a few per cent of the time often has 64 equal samples and a variance estimate of 0."""
    return z_test(expected, res.image.astype(np.float64),
                  reference_variance=expected * (1.0 - expected) / SPP)


@pytest.mark.parametrize("case", list(CASES))
def test_motion_blur_matches_the_exact_time_integral(tmp_path, case):
    """The blurred image equals the exact shutter integral (per-pixel Z-test; 64 jittered
    samples per pixel, each at its own time); the still scene and the motion at half the
    speed fail the same test, so the blur is both there and of the right extent."""
    motion = CASES[case]
    scene = _scene(tmp_path, **motion)
    res = DIST.render(scene, DIST.parse_params({"spp": SPP, "max_depth": 1}), seed=3)
    exact = exact_image(scene.camera, **motion)
    still = exact_image(scene.camera)
    half = exact_image(scene.camera, **{k: tuple(0.5 * np.asarray(v)) for k, v in motion.items()})
    assert np.abs(exact - still).max() > 0.3, "the motion must change the image"
    z = _ztest(exact, res)
    print(f"{case}: {z}; still {_ztest(still, res).fraction:.4f}, half speed {_ztest(half, res).fraction:.4f}")
    assert z.passed, f"{case}: {z}"
    assert not _ztest(still, res).passed
    assert not _ztest(half, res).passed


@pytest.mark.parametrize("extra", [{"dimensions": "stratified"}, {"sampler": "sobol"}],
                         ids=["stratified", "sobol"])
@pytest.mark.parametrize("case", ["camera translation", "mesh rotation"])
def test_stratified_and_sobol_shutter_times_give_the_exact_time_integral(tmp_path, case, extra):
    """The shutter time as a stratified dimension (shuffled spp strata per pixel) or a
    scrambled van der Corput dimension (sampler=sobol): the same exact integral
    passes, the half-speed motion fails."""
    motion = CASES[case]
    scene = _scene(tmp_path, **motion)
    res = DIST.render(scene, DIST.parse_params({"spp": SPP, "max_depth": 1, **extra}), seed=3)
    z = _ztest(exact_image(scene.camera, **motion), res)
    half = exact_image(scene.camera, **{k: tuple(0.5 * np.asarray(v)) for k, v in motion.items()})
    print(f"{case} {extra}: {z}; half speed {_ztest(half, res).fraction:.4f}")
    assert z.passed, f"{case} {extra}: {z}"
    assert not _ztest(half, res).passed


def test_motion_is_read_checked_and_refused_where_not_modelled(tmp_path):
    scene = _scene(tmp_path, cam_v=(1, 0, 0), mesh_w=(0, 0, 2))
    assert scene.camera.velocity.tolist() == [1, 0, 0] and scene.camera.angular_velocity is None
    square = scene.shapes[1]
    assert square.angular_velocity.tolist() == [0, 0, 2]
    assert np.allclose(square.pivot, [0, 0, -D_SQUARE])                 # default: the centroid
    for name in ("raycast", "whitted", "path"):
        with pytest.raises(NotImplementedError, match="camera motion"):
            registry.get(name).render(scene, registry.get(name).parse_params({}))
    with pytest.raises(ValueError, match="packets=true"):
        DIST.render(scene, DIST.parse_params({"spp": 4, "packets": True}))
    with pytest.raises(NotImplementedError, match="moving spheres or meshes"):
        DIST.render(scene, DIST.parse_params({"spp": 4, "accel": "bvh-sah"}))
    bad = tmp_path / "bad.xml"
    bad.write_text(SCENE.format(camera="", back=D_BACK, square=D_SQUARE, half=HALF,
                                mesh=_vec("gibench_velocity", (1, 0, 0)) +
                                '<emitter type="area"><rgb name="radiance" value="1"/></emitter>'))
    with pytest.raises(ValueError, match="bad.xml:.*moving mesh cannot be an emitter"):
        load_scene(bad)
    bad.write_text(SCENE.format(camera=_vec("gibench_angular_velocity", (0, "nan", 0)), back=D_BACK,
                                square=D_SQUARE, half=HALF, mesh=""))
    with pytest.raises(ValueError, match="bad.xml:6: <vector>: not a finite number"):
        load_scene(bad)


def test_still_scene_renders_as_before(tmp_path):
    """Motion with zero speed changes nothing: the image equals the static scene's bit for bit
    (the time dimension is drawn but unused)."""
    a = DIST.render(_scene(tmp_path), DIST.parse_params({"spp": 4}), seed=1).image
    b = DIST.render(_scene(tmp_path, cam_v=(0, 0, 0), mesh_w=(0, 0, 0)),
                    DIST.parse_params({"spp": 4}), seed=1).image
    np.testing.assert_array_equal(a, b)


def test_mitsuba_shutter_reference_refuses_camera_and_mesh_motion(tmp_path):
    """The shutter-averaged Mitsuba reference moves spheres only: a scene with camera or
    mesh motion gets one line naming the element and line instead of a wrong reference."""
    from core.errors import SceneError
    from references.motion_blur import has_motion, scene_at_time

    for motion, where in ((dict(cam_v=(1, 0, 0)), "on a sensor 'perspective'"),
                          (dict(mesh_w=(0, 0, 1)), "on a shape 'rectangle'")):
        scene = _scene(tmp_path, **motion)
        assert has_motion(scene.path)
        with pytest.raises(SceneError, match=f"motion.xml:\\d+: gibench_\\w+ {where}: .*spheres only"):
            scene_at_time(scene.path, 0.5)
