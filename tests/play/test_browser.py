"""``bimgame play`` in a real headless browser: Debian's chromium driven by Playwright against the real
server (a ``bimgame play`` process). The page shows frames, keys move the marble, an episode played
with keys becomes a valid dataset, a misbehaving websocket client and a second tab break nothing,
and SIGTERM / SIGINT stop the server cleanly.

Needs ``/usr/bin/chromium`` (``apt-get update && apt-get install -y --no-install-recommends
chromium``; CI's ``.ci/run`` installs it): without it these tests are skipped, saying so, so that
``./dev test`` passes on a fresh machine. They also need Playwright for Python (the ``dev`` extra,
which ``./dev`` installs: its absence fails them). Playwright's own browser download is never used. ``BIMGAME_UPDATE_DOCS=1`` also saves the page's screenshot to
``docs/play/play.png``.
"""

from __future__ import annotations

import asyncio
import json
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import aiohttp
import numpy as np
import pytest

from bimgame.expert.datasets import iterate_sequences, load_dataset
from bimgame.expert.minari_build import episode_path
from bimgame.play.controls import KEY_ACTIONS

try:
    from playwright.sync_api import sync_playwright
except ImportError:  # reported by the fixture, as a failure with the fix
    sync_playwright = None

CHROMIUM = "/usr/bin/chromium"
CHROMIUM_ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                 "--disable-background-networking", "--disable-component-update", "--disable-sync"]
DOCS_SCREENSHOT = Path(__file__).resolve().parents[2] / "docs" / "play" / "play.png"
START_TIMEOUT = 90  # s for the server to print its URL (imports torch and MuJoCo on a busy machine)
WAIT_MS = 60_000  # ms for anything the page should show


@pytest.fixture
def browser():
    if not Path(CHROMIUM).exists():
        pytest.skip(f"chromium not installed ({CHROMIUM} not found): apt-get install chromium "
                    "(apt-get update && apt-get install -y --no-install-recommends chromium)")
    if sync_playwright is None:
        pytest.fail("Playwright for Python is not installed: pip install -e '.[dev]' (do not run 'playwright "
                    "install': the test uses /usr/bin/chromium)")
    with sync_playwright() as playwright:
        browser = playwright.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
        try:
            yield browser
        finally:
            browser.close()


class Server:
    """A ``bimgame play --port 0`` process; its URL is read from what it prints."""

    def __init__(self, tmp_path: Path, *args: str):
        self.log = tmp_path / "server.log"
        self._log_handle = open(self.log, "w")
        self.process = subprocess.Popen([sys.executable, "-m", "bimgame.cli.main", "play", "--port", "0", *args],
                                        stdout=subprocess.PIPE, stderr=self._log_handle, text=True, cwd=tmp_path)
        lines: list[str] = []
        reader = threading.Thread(target=lambda: lines.append(self.process.stdout.readline()), daemon=True)
        reader.start()
        reader.join(START_TIMEOUT)
        if not lines or "open http" not in lines[0]:
            self.stop(signal.SIGKILL)
            pytest.fail(f"the server did not start: {lines!r}\n{self.log.read_text()}")
        self.url = lines[0].split("open ", 1)[1].split()[0]

    def stop(self, sig=signal.SIGTERM, timeout: float = 60) -> int:
        if self.process.poll() is None:
            self.process.send_signal(sig)
        try:
            code = self.process.wait(timeout)
        except subprocess.TimeoutExpired:
            self.process.kill()
            code = self.process.wait()
            pytest.fail(f"the server did not stop within {timeout} s of {sig!r}:\n{self.log.read_text()}")
        self._log_handle.close()
        return code

    def ensure_stopped(self) -> None:
        if self.process.poll() is None:
            self.process.kill()
            self.process.wait()
        self._log_handle.close()


def state(page) -> dict:
    return page.evaluate("() => window.bimgamePlay.state")


def wait_for(page, condition: str, what: str) -> None:
    """Wait until the JS ``condition`` on ``s`` (the last state) and ``p`` (window.bimgamePlay) holds."""
    try:
        page.wait_for_function(
            f"() => {{ const p = window.bimgamePlay; const s = p.state; return !!(s && ({condition})); }}",
            timeout=WAIT_MS, polling=50)
    except Exception as error:
        raise AssertionError(f"the page never showed {what} ({condition}); last state {state(page)}") from error


def open_page(browser, url: str):
    page = browser.new_page(viewport={"width": 1000, "height": 660})
    page.goto(url)
    wait_for(page, "p.frames >= 5", "frames")
    return page


class AsyncInThread(threading.Thread):
    """Run the coroutine function ``run`` in a thread with its own event loop (Playwright's sync API
    owns this one's); :meth:`join` raises what it raised."""

    def __init__(self, run):
        super().__init__(daemon=True)
        self._run, self.error = run, None
        self.start()

    def run(self) -> None:
        try:
            asyncio.run(self._run())
        except BaseException as error:  # handed to join()
            self.error = error

    def join(self, timeout=None) -> None:
        super().join(timeout)
        if self.is_alive():
            raise AssertionError(f"the websocket client did not finish within {timeout} s")
        if self.error is not None:
            raise self.error


def misbehave(url: str) -> list[dict]:
    """A raw websocket client sending malformed messages (in its own thread's event loop); returns the
    server's error replies. Also checks that a websocket from another site is refused."""
    malformed = ["not json", "[1, 2]", '{"type": "jump"}', '{"type": "keys", "held": ["jump"]}',
                 '{"type": "keys", "held": [2]}', '{"type": "control", "who": "agent"}', "{" * 3000]
    replies: list[dict] = []

    async def run() -> None:
        async with aiohttp.ClientSession() as http:
            with pytest.raises(aiohttp.WSServerHandshakeError) as refused:
                await http.ws_connect(url + "ws", headers={"Origin": "http://elsewhere.example"})
            assert refused.value.status == 403
            port = url.rstrip("/").rsplit(":", 1)[1]
            async with http.get(url, headers={"Host": f"rebound.example:{port}"}) as response:
                assert response.status == 403  # a name resolved to 127.0.0.1 by someone else
            async with http.get(url + "static/play.js") as response:
                assert response.status == 200 and "bimgamePlay" in await response.text()
            async with http.ws_connect(url + "ws") as ws:
                for text in malformed:
                    await ws.send_str(text)
                await ws.send_bytes(b"\x89PNG junk")
                deadline = time.monotonic() + 30
                while len(replies) < len(malformed) + 1 and time.monotonic() < deadline:
                    message = await ws.receive(timeout=30)
                    if message.type == aiohttp.WSMsgType.TEXT and json.loads(message.data)["type"] == "error":
                        replies.append(json.loads(message.data))

    AsyncInThread(run).join(60)
    return replies


def vanish_holding(url: str, key: str, seconds: float) -> AsyncInThread:
    """A client that holds ``key`` for ``seconds`` and disappears without a closing handshake."""

    async def run() -> None:
        async with aiohttp.ClientSession() as http:
            ws = await http.ws_connect(url + "ws")
            await ws.send_str(json.dumps({"type": "keys", "held": [key]}))
            await asyncio.sleep(seconds)
        # leaving the session drops the connection under the open websocket

    return AsyncInThread(run)


def test_play_record_and_survive_bad_clients_in_a_browser(browser, tmp_path, x_axis_seed):
    record = tmp_path / "data" / "human"
    server = Server(tmp_path, "--task", "STG1", "--max-steps", "120", "--record", "data/human", "--seed",
                    str(x_axis_seed))  # a relative path, as the page shows it (the server runs in tmp_path)
    try:
        page = open_page(browser, server.url)
        s = state(page)
        assert s["task"] == "STG1" and s["phase"] == "ready" and s["step"] == 0 and s["recording"]["episodes"] == 0
        blank = page.evaluate("""() => { const c = document.getElementById('view');
            const d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data;
            let lo = 255, hi = 0;
            for (let i = 0; i < d.length; i += 4) { lo = Math.min(lo, d[i]); hi = Math.max(hi, d[i]); }
            return hi - lo; }""")
        assert blank > 100, "the canvas shows no maze"

        # Up: the marble rolls up the screen (+y) along its channel.
        x0, y0 = s["marble"]
        page.keyboard.down("ArrowUp")
        wait_for(page, "s.step >= 12", "12 steps with ArrowUp held")
        page.keyboard.up("ArrowUp")
        x1, y1 = state(page)["marble"]
        assert y1 - y0 > 0.004, (x0, y0, x1, y1)

        # Right until the time limit: the episode is recorded and the dataset rebuilt.
        page.keyboard.down("ArrowRight")
        wait_for(page, "s.last && s.last.recorded === 0", "the first episode recorded")
        page.keyboard.up("ArrowRight")
        wait_for(page, "s.recording.built === 1", "the dataset built")
        (episode,) = list(iterate_sequences(record, obs="state"))
        actions = list(episode.actions)
        assert len(actions) == 120 and episode.truncated and set(actions) <= {0, 2, 3}
        assert actions[0] == 2 and actions.count(2) >= 12 and actions[-1] == 3
        moved = episode.state_obs[12, :2] - episode.state_obs[0, :2]  # 12 steps of ArrowUp: up the screen
        assert moved[1] > 0.004 and abs(moved[0]) < 0.5 * moved[1], moved

        # A misbehaving client gets errors and breaks nothing for this page.
        replies = misbehave(server.url)
        assert len(replies) == 8 and all(r["message"] for r in replies), replies
        frames = page.evaluate("() => window.bimgamePlay.frames")
        wait_for(page, f"p.frames > {frames + 10} && s.clients === 1", "frames after the bad clients left")

        # A second tab sees the same game and can control it; closed with a key held, it releases it.
        wait_for(page, "s.phase === 'ready'", "the next episode ready")
        second = open_page(browser, server.url)
        wait_for(page, "s.clients === 2", "two tabs")
        episode_before = state(page)["episode"]
        second.keyboard.down("ArrowDown")
        wait_for(page, "s.step >= 5 && s.key === 'down'", "the second tab's key in the first tab")
        second.close()
        wait_for(page, "s.clients === 1 && s.key === null && s.action === 'noop'", "the closed tab's key released")
        page.keyboard.press("r")
        wait_for(page, f"s.episode === {episode_before + 1} && s.step === 0", "the reset")

        # A client that vanishes while holding a key: its key is released too.
        page.keyboard.down("ArrowLeft")
        wait_for(page, "s.phase === 'running' && s.key === 'left'", "ArrowLeft held")
        vanishing = vanish_holding(server.url, "down", 0.5)
        wait_for(page, "s.key === 'down' && s.clients === 2", "the other client's key")
        vanishing.join(30)
        wait_for(page, "s.key === 'left' && s.clients === 1", "the vanished client's key released")

        # The frame rate (over the last 2 s), and the screenshot of a game in progress.
        fps = page.evaluate("() => window.bimgamePlay.fps")
        s = state(page)
        print(f"\npage frame rate {fps:.1f}/s, server loop {s['server_hz']:.1f} Hz")
        assert fps > 5, f"the page shows {fps:.1f} frames/s"  # 30 on an idle machine; CI's is busy
        shot = tmp_path / "play.png"
        page.screenshot(path=str(shot))
        if os.environ.get("BIMGAME_UPDATE_DOCS") == "1":
            DOCS_SCREENSHOT.parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(shot, DOCS_SCREENSHOT)

        # SIGTERM mid-episode: the person's steps so far are recorded (truncated) and the server stops.
        page.keyboard.up("ArrowLeft")
        episode = state(page)["episode"]
        page.keyboard.press("r")  # a fresh episode, whether the last one still ran or not
        wait_for(page, f"s.episode === {episode + 1}", "the reset")
        page.keyboard.down("ArrowDown")
        wait_for(page, f"s.episode === {episode + 1} && s.phase === 'running' && s.recorded_steps >= 3",
                 "a running episode")
        assert server.stop(signal.SIGTERM) == 0, server.log.read_text()
        wait_for(page, "!p.connected && document.getElementById('error').textContent.includes('stopped')",
                 "the server's goodbye")
        log = server.log.read_text()
        assert "4 episodes, dataset complete" in log, log
        episodes = list(load_dataset(record).iterate_episodes())
        reasons = [str(np.load(episode_path(record, i))["end_reason"]) for i in range(len(episodes))]
        # the first, the second tab's (reset), ArrowLeft's (reset by R, or the time limit), the interrupted one
        assert reasons[:2] == ["time limit", "reset"] and reasons[3] == "server stopped", reasons
        assert all(e.truncations[-1] for e in episodes)
        assert set(episodes[3].actions) == {KEY_ACTIONS["down"]}
    finally:
        server.ensure_stopped()


def test_agent_plays_in_the_page_and_h_takes_over(browser, tmp_path, tiny_agent_run):
    server = Server(tmp_path, "--agent", str(tiny_agent_run), "--max-steps", "300")
    try:
        page = open_page(browser, server.url)
        wait_for(page, "s.controller === 'agent' && s.step >= 10", "the agent playing without a key")
        assert state(page)["task"] == "STG1" and page.is_visible("#control")
        page.keyboard.press("h")
        wait_for(page, "s.controller === 'human'", "H: the person in control")
        page.keyboard.down("d")
        wait_for(page, "s.action === 'right'", "D tilting right")
        page.keyboard.up("d")
        page.click("#control")  # the button hands it back
        wait_for(page, "s.controller === 'agent'", "the agent in control again")
        page.keyboard.press("g")
        wait_for(page, "s.agent.greedy === false", "G: sampled actions")
        assert server.stop(signal.SIGINT) == 0, server.log.read_text()
    finally:
        server.ensure_stopped()


def test_the_labyrinth_in_the_page_the_expert_plays_and_keys_take_over(browser, tmp_path):
    """``--task LABYRINTH-HARD --agent expert``: the page shows the labyrinth, its path progress and tilt
    (no gauge, no greedy switch for the expert); H hands the board to the keys, and left then down from
    the start drops the marble into a hole, which the end screen says."""
    server = Server(tmp_path, "--task", "LABYRINTH-HARD", "--agent", "expert")
    try:
        page = open_page(browser, server.url)
        wait_for(page, "s.puzzle === 'labyrinth' && s.controller === 'agent' && s.step >= 10 && s.progress > 0",
                 "the expert playing the labyrinth")
        assert page.text_content("#title") == "Labyrinth" and "MPC expert" in page.text_content("#controller")
        assert page.is_visible("#progress-row") and page.text_content("#progress").endswith("%")
        assert page.is_visible("#tilt-row") and not page.is_visible("#greedy-label")
        assert not page.is_visible("#gauge-note")
        page.keyboard.press("h")
        wait_for(page, "s.controller === 'human'", "H: the person in control")
        page.keyboard.press("r")
        wait_for(page, "s.phase === 'ready' && s.step === 0", "a new episode waiting for a key")
        page.keyboard.down("ArrowLeft")
        wait_for(page, "s.step >= 30 && s.action === 'left' && s.tilt_deg[1] < -5", "ArrowLeft tilting about -y")
        page.keyboard.down("ArrowDown")  # the latest key counts
        wait_for(page, "s.phase === 'over'", "the episode's end")
        page.keyboard.up("ArrowDown")
        page.keyboard.up("ArrowLeft")
        assert state(page)["last"]["reason"] == "hole", state(page)["last"]
        assert "hole" in page.text_content("#overlay")
        assert server.stop(signal.SIGINT) == 0, server.log.read_text()
    finally:
        server.ensure_stopped()
