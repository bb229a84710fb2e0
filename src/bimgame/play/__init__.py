"""``bimgame play``: people play the Ball-in-Maze Game in a browser, watch a trained agent, take over
from it, and have their play recorded as a Minari dataset (README, "Playing in a browser").

- :mod:`~bimgame.play.controls` — keys to the env's discrete actions, held keys of every client.
- :mod:`~bimgame.play.agent` — a trained policy acting step by step (greedy or sampled).
- :mod:`~bimgame.play.session` — the game loop's state machine, independent of the web.
- :mod:`~bimgame.play.recording` — the person's episodes as a resumable Minari dataset directory.
- :mod:`~bimgame.play.minari_human` — the child process that builds that Minari dataset.
- :mod:`~bimgame.play.protocol` — the websocket messages, parsed and checked.
- :mod:`~bimgame.play.server` — the aiohttp application: the page, the websocket, the 30 Hz loop.
"""
