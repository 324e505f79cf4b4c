"""``jaxanim view``: the viser viewer's scene and timeline, the command, and a screenshot of the page
in a real headless browser.

The browser test drives Debian's Chromium through its own command line (``chromium --headless
--screenshot``; no Playwright, no WebDriver): software WebGL (SwiftShader) draws the three.js scene,
the page's websocket talks to the viser server in this process, and ``--virtual-time-budget`` lets
the page run until it is idle before the screenshot. The test retries with a longer budget until
the skeleton's magenta (the centre-line bones, a colour the viser page itself never uses) shows up,
then hides the bones and checks that the magenta goes away. It skips, saying so, where no
``chromium`` is installed (``apt-get install chromium``).
"""

from __future__ import annotations

import shutil
import subprocess

import numpy as np
import pytest

pytest.importorskip("viser", reason="the viewer needs viser (jaxanim[view])")

import jaxanim
from jaxanim import cli
from jaxanim.app._common import _UI, _load
from jaxanim.app._view import BONE_RGB, Viewer, build_viewer

_WINDOW = (800, 600)  # the browser window, pixels
_BUDGETS_MS = (4000, 15000)  # virtual time the page gets before the screenshot, tried in turn
_MIN_MAGENTA = 40  # pixels of bone magenta in an 800 x 600 screenshot
# The flags the machine notes give for headless Chromium here (root, no network beyond loopback),
# plus software WebGL.
_CHROMIUM_FLAGS = (
    "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
    "--disable-background-networking", "--disable-component-update", "--disable-sync",
    "--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--hide-scrollbars",
)


def _run(capsys, *argv) -> tuple[int, str, str]:
    code = cli.main(["--no-compile-cache", *(str(a) for a in argv)])
    captured = capsys.readouterr()
    return code, captured.out, captured.err


@pytest.fixture(scope="module")
def viewer():
    """The shipped clip twice (a second file path), paused at step 0, on a free port."""
    clips = [_load(None, _UI(quiet=True), np.float64), _load(str(jaxanim.default_clip_path()), _UI(quiet=True), np.float64)]
    v = build_viewer(clips, port=0, playing=False)
    yield v
    v.close()


def test_viewer_scene_and_timeline(viewer: Viewer):
    assert viewer.url.startswith("http://127.0.0.1:") and viewer.server.get_port() > 0
    assert viewer.num_steps == 120 and viewer.frame.max == 119 and viewer.fps.value == 30
    assert viewer.playing.value is False
    a, b = viewer.clips
    assert a.bones.points.shape == (a.pairs.shape[0], 2, 3) == (25, 2, 3)  # 20 bones + 5 End Sites
    assert a.joints.points.shape == (21, 3)
    # side by side: the second clip's X range over all frames starts right of the first one's
    assert b.points[..., 0].min() > a.points[..., 0].max()
    start = a.bones.points.copy()
    viewer.frame.value = 60  # what moving the slider does
    assert viewer.time.value == "2.00 s"
    assert np.abs(a.bones.points - start).max() > 0.1, "the bones did not move"
    np.testing.assert_allclose(a.joints.points, a.points[60, :21], atol=1e-6, err_msg="field: joints at step 60")
    viewer.frame.value = 0
    np.testing.assert_array_equal(a.bones.points, start)


def test_viewer_plays(viewer: Viewer):
    import threading

    stop = threading.Event()
    viewer.playing.value = True
    viewer.fps.value = 100
    t = threading.Thread(target=viewer.run, args=(stop,))
    t.start()
    try:
        stop.wait(0.3)
    finally:
        stop.set()
        t.join(5)
        viewer.playing.value = False
        viewer.fps.value = 30
    assert viewer.frame.value > 0, "playback did not advance the frame slider"
    viewer.frame.value = 0


def _screenshot(url: str, path, user_data_dir, budget_ms: int):
    from PIL import Image

    cmd = [shutil.which("chromium"), *_CHROMIUM_FLAGS, f"--user-data-dir={user_data_dir}",
           f"--window-size={_WINDOW[0]},{_WINDOW[1]}", f"--virtual-time-budget={budget_ms}",
           f"--screenshot={path}", url]
    # 180 s: it takes about 8 s alone, and once timed out at 90 s while the suite's other worker was busy
    subprocess.run(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, timeout=180, check=True)
    with Image.open(path) as im:
        return np.asarray(im.convert("RGB"), dtype=np.int64)


def _magenta(img: np.ndarray) -> int:
    """Pixels of the centre-line bone colour's hue (R and B well above G, and close to each other),
    whatever tone mapping and the page's fade-in do to its brightness: on a loaded machine the
    screenshot can catch the bones pale (a pale magenta, e.g. (240, 180, 240), drew 0 pixels under a
    test for R, B > 150 and G < 100)."""
    r, g, b = img[..., 0], img[..., 1], img[..., 2]
    return int(((r - g > 40) & (b - g > 40) & (np.abs(r - b) < 60)).sum())


@pytest.mark.skipif(shutil.which("chromium") is None,
                    reason="no browser: Chromium is not installed (apt-get install chromium) for the screenshot test")
def test_viewer_in_headless_chromium(viewer: Viewer, tmp_path):
    assert BONE_RGB["center"] == (220, 0, 220)  # what _magenta looks for
    viewer.frame.value = 15
    for budget in _BUDGETS_MS:  # wait until the scene is drawn: a longer budget if the bones are not there yet
        img = _screenshot(viewer.url, tmp_path / "view.png", tmp_path / "profile", budget)
        if _magenta(img) >= _MIN_MAGENTA:
            break
    assert img.shape == (_WINDOW[1], _WINDOW[0], 3)
    n = _magenta(img)
    assert n >= _MIN_MAGENTA, f"{n} magenta pixels in the screenshot: the skeleton is not drawn ({tmp_path / 'view.png'})"
    assert (img.reshape(-1, 3).std(axis=0) > 5).all(), "a blank page"
    # the control: the same page with the bones hidden has no magenta
    for c in viewer.clips:
        c.bones.visible = False
    try:
        hidden = _screenshot(viewer.url, tmp_path / "hidden.png", tmp_path / "profile", budget)
    finally:
        for c in viewer.clips:
            c.bones.visible = True
    assert _magenta(hidden) < _MIN_MAGENTA // 4, "magenta without the bones: the check does not see the skeleton"


def test_view_command_prints_the_url_and_stops(capsys, monkeypatch):
    def interrupted(self, stop=None):
        raise KeyboardInterrupt

    monkeypatch.setattr(Viewer, "run", interrupted)
    code, out, err = _run(capsys, "view", "--port", "0")
    assert code == 0, err
    assert "viewing walk.bvh (the shipped default clip) at http://127.0.0.1:" in out
    assert "starting the viewer" in err


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["missing.bvh"], "error: missing.bvh: cannot read the file"),
        (["--port", "70000"], "error: --port 70000: expected 0 to 65535"),
        (["--host", "999.1.1.1"], "error: --host 999.1.1.1: not an IP address or a host name"),
        (["--host", "192.0.2.1"], "error: --host 192.0.2.1: cannot listen on it"),  # TEST-NET-1: no local interface
    ],
    ids=["missing", "port", "host-syntax", "host-not-local"],
)
def test_view_bad_input(capsys, argv, message):
    code, _, err = _run(capsys, "view", *argv)
    assert code == 2 and message in err, err
    assert "Traceback" not in err


def test_viewer_mesh():
    clip = _load(None, _UI(quiet=True), np.float64)
    v = build_viewer([clip], port=0, mesh=True, playing=False)
    try:
        c = v.clips[0]
        assert c.mesh is not None and c.vertices.shape[0] == 120
        first = np.asarray(c.mesh.vertices).copy()
        v.frame.value = 30
        assert np.abs(np.asarray(c.mesh.vertices) - first).max() > 0.05, "the mesh did not move"
    finally:
        v.close()
