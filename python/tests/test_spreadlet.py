"""The Python module against the command line and against bad input.

Run from the repository root after `pip install ./python`:
    SPREADLET_BIN=target/release/spreadlet SPREADLET_SCENE_BIN=target/release/spreadlet-scene \
        python -m pytest python/tests
"""

import os
import subprocess

import numpy as np
import pytest

import spreadlet

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def binary(env, name):
    path = os.environ.get(env) or os.path.join(ROOT, "target", "release", name)
    if not os.path.exists(path):
        pytest.fail(f"{name} not found at {path}: set {env} or build it")
    return path


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    """A built-in scene with depth of field and motion blur, as a G-buffer and its camera."""
    d = tmp_path_factory.mktemp("scene")
    g, cam = str(d / "g.exr"), str(d / "camera.json")
    subprocess.run([binary("SPREADLET_SCENE_BIN", "spreadlet-scene"), "render", "crossing",
                    "--width", "64", "--gbuffer", g, "--aa", "4", "--deep", str(d / "deep.exr"),
                    "--stochastic",
                    str(d / "frames.exr"), "--spp", "2", "--camera-out", cam, "--quiet"],
                   check=True)
    return d, g, cam


def test_the_module_writes_what_the_cli_writes(scene):
    d, g, cam = scene
    out = str(d / "cli.exr")
    subprocess.run([binary("SPREADLET_BIN", "spreadlet"), "synth", "--input", g, "--camera", cam,
                    "--out", out, "--backend", "cpu", "-q"], check=True)
    gbuffer = spreadlet.read_gbuffer(g)
    camera = spreadlet.Camera.from_json(cam)
    r = spreadlet.Renderer(backend="cpu")
    assert gbuffer.acceleration is not None and gbuffer.acceleration.shape == gbuffer.motion.shape
    image = r.synthesize(gbuffer.color, gbuffer.depth, gbuffer.motion, camera,
                         acceleration=gbuffer.acceleration)
    cli = spreadlet.read_gbuffer(out).color
    assert image.dtype == np.float32 and image.shape == (camera.height, camera.width, 4)
    assert np.array_equal(image, cli), "the module and the CLI differ"
    assert not np.array_equal(image, gbuffer.color), "nothing was blurred"


def test_a_second_call_reuses_the_databases(scene):
    _, g, cam = scene
    gbuffer = spreadlet.read_gbuffer(g)
    camera = spreadlet.Camera.from_json(cam)
    r = spreadlet.Renderer(backend="cpu")
    first, stats1 = r.synthesize(gbuffer.color, gbuffer.depth, gbuffer.motion, camera, stats=True)
    second, stats2 = r.synthesize(gbuffer.color, gbuffer.depth, gbuffer.motion, camera, stats=True)
    assert stats1["databases_loaded"] > 0 and stats2["databases_loaded"] == 0
    assert r.database_loads == 1
    assert stats1["defocus"] and stats1["motion"]
    assert np.array_equal(first, second)
    scores = spreadlet.compare(first, second)
    assert scores["ssim"] == pytest.approx(1.0) and scores["psnr_db"] is None


def test_bad_input_raises_value_error(scene):
    _, g, cam = scene
    gbuffer = spreadlet.read_gbuffer(g)
    camera = spreadlet.Camera.from_json(cam)
    r = spreadlet.Renderer(backend="cpu")
    with pytest.raises(ValueError, match="shape"):
        r.synthesize(gbuffer.color[:, :, :3].copy(), gbuffer.depth, gbuffer.motion, camera)
    with pytest.raises(ValueError, match="depth"):
        r.synthesize(gbuffer.color, gbuffer.depth[:-1].copy(), gbuffer.motion, camera)
    bad = gbuffer.depth.copy()
    bad[3, 5] = np.nan
    with pytest.raises(ValueError, match="(?i)depth"):
        r.synthesize(gbuffer.color, bad, gbuffer.motion, camera)
    with pytest.raises(ValueError, match="acceleration"):
        r.synthesize(gbuffer.color, gbuffer.depth, gbuffer.motion, camera,
                     acceleration=gbuffer.motion[:-1].copy())
    with pytest.raises(ValueError, match="f_stop"):
        spreadlet.Camera(64, 64, 50.0, 36.0, f_stop=-1.0, focus_distance=1.0)
    with pytest.raises(ValueError, match="backend"):
        spreadlet.Renderer(backend="quantum")
    with pytest.raises(ValueError):
        spreadlet.read_gbuffer(os.path.join(ROOT, "no-such-file.exr"))


def test_reconstruct_writes_what_the_cli_writes(scene):
    d, _, cam = scene
    frames_path, out = str(d / "frames.exr"), str(d / "cli-reconstruct.exr")
    subprocess.run([binary("SPREADLET_BIN", "spreadlet"), "reconstruct", "--input", frames_path,
                    "--camera", cam, "--out", out, "--backend", "cpu", "-q"], check=True)
    camera = spreadlet.Camera.from_json(cam)
    # The scene renderer writes the denoiser's guides, and the CLI uses them.
    frames, guides = spreadlet.read_frames(frames_path, guides=True)
    assert guides is not None
    assert frames.shape == (camera.height, camera.width, 2, len(spreadlet.SAMPLE_CHANNELS))
    assert frames.dtype == np.float32
    r = spreadlet.Renderer(backend="cpu")
    from_array, stats = r.reconstruct(frames, camera, stats=True, guides=guides)
    from_path = r.reconstruct(frames_path, camera)
    cli = spreadlet.read_gbuffer(out).color
    assert np.array_equal(from_array, cli), "the module and the CLI differ"
    assert np.array_equal(from_path, cli)
    assert stats["defocus"] and stats["motion"]
    # The plain average of the samples is not what comes back.
    average = frames[:, :, :, :4].mean(axis=2)
    assert not np.allclose(from_array, average, atol=1e-3)
    with pytest.raises(ValueError, match="shape"):
        r.reconstruct(frames[:, :, :, :11].copy(), camera)
    with pytest.raises(ValueError, match="camera"):
        r.reconstruct(frames[:32].copy(), camera)


def test_reconstruct_takes_the_denoiser_guides(scene):
    d, _, cam = scene
    frames_path = str(d / "frames.exr")
    camera = spreadlet.Camera.from_json(cam)
    # The scene renderer writes the guides: what each sample's ray hit, its albedo and its
    # camera-space normal (unit length on a hit; every ray of this scene hits the wall or more).
    frames, guides = spreadlet.read_frames(frames_path, guides=True)
    assert list(spreadlet.GUIDE_CHANNELS) == ["albedo.R", "albedo.G", "albedo.B",
                                              "normal.X", "normal.Y", "normal.Z"]
    assert guides.shape == frames.shape[:3] + (6,) and guides.dtype == np.float32
    assert np.allclose(np.linalg.norm(guides[..., 3:], axis=-1), 1.0, atol=1e-4)
    assert spreadlet.read_frames(frames_path).shape == frames.shape
    r = spreadlet.Renderer(backend="cpu")
    image = r.reconstruct(frames, camera, guides=guides)
    assert image.shape == (camera.height, camera.width, 4) and np.isfinite(image).all()
    assert np.array_equal(image, r.reconstruct(frames_path, camera))
    with pytest.raises(ValueError, match="guides must have shape"):
        r.reconstruct(frames, camera, guides=guides[:, :, :1].copy())
    guides[3, 4, 1, 4] = np.nan
    with pytest.raises(ValueError, match="normal.Y"):
        r.reconstruct(frames, camera, guides=guides)


def test_progress_reaches_the_callback_while_a_database_is_built(scene, tmp_path):
    _, g, cam = scene
    gbuffer = spreadlet.read_gbuffer(g)
    camera = spreadlet.Camera.from_json(cam)
    # An empty cache folder: the first call builds its databases (the small test profile).
    r = spreadlet.Renderer(backend="cpu", db_profile="test", cache_dir=str(tmp_path))
    heard = []
    _, stats = r.synthesize(gbuffer.color, gbuffer.depth, gbuffer.motion, camera, stats=True,
                            progress=lambda message, fraction: heard.append((message, fraction)))
    assert stats["databases_built"] == stats["databases_loaded"] > 0
    fractions = [f for _, f in heard if f is not None]
    assert any("building" in m for m, f in heard if f is None), heard
    assert fractions and max(fractions) == 1.0 and all(0.0 < f <= 1.0 for f in fractions)
    # Built once: a second renderer on the same folder builds nothing and hears nothing.
    again = []
    _, stats = spreadlet.Renderer(backend="cpu", db_profile="test", cache_dir=str(tmp_path)) \
        .synthesize(gbuffer.color, gbuffer.depth, gbuffer.motion, camera, stats=True,
                    progress=lambda m, f: again.append(m))
    assert stats["databases_built"] == 0 and again == []


def test_an_exception_in_the_progress_callback_is_raised(scene, tmp_path):
    _, g, cam = scene
    gbuffer = spreadlet.read_gbuffer(g)
    camera = spreadlet.Camera.from_json(cam)
    r = spreadlet.Renderer(backend="cpu", db_profile="test", cache_dir=str(tmp_path))

    def cancel(message, fraction):
        raise KeyError("stop")

    with pytest.raises(KeyError, match="stop"):
        r.synthesize(gbuffer.color, gbuffer.depth, gbuffer.motion, camera, progress=cancel)
    with pytest.raises(ValueError, match="callable"):
        r.synthesize(gbuffer.color, gbuffer.depth, gbuffer.motion, camera, progress=3)


def test_synthesize_deep_writes_what_the_cli_writes(scene):
    d, _, cam = scene
    deep, out = str(d / "deep.exr"), str(d / "cli-deep.exr")
    subprocess.run([binary("SPREADLET_BIN", "spreadlet"), "synth", "--input", deep,
                    "--camera", cam, "--out", out, "--backend", "cpu", "-q"], check=True)
    camera = spreadlet.Camera.from_json(cam)
    r = spreadlet.Renderer(backend="cpu")
    image, stats = r.synthesize_deep(deep, camera, stats=True)
    assert np.array_equal(image, spreadlet.read_gbuffer(out).color), "the module and the CLI differ"
    assert stats["defocus"] and stats["motion"]
    with pytest.raises(ValueError, match="(?i)deep"):
        r.synthesize_deep(os.path.join(d, "g.exr"), camera)


def test_camera_names_a_real_lens():
    cam = spreadlet.Camera(width=64, height=64, focal_length_mm=50, sensor_width_mm=36,
                           f_stop=2.8, focus_distance=1.2, lens="double-gauss-50mm")
    assert cam.width == 64
    with pytest.raises(ValueError, match="double-gauss-50mm"):
        spreadlet.Camera(width=64, height=64, focal_length_mm=50, sensor_width_mm=36,
                         f_stop=2.8, focus_distance=1.2, lens="no-such-lens")
