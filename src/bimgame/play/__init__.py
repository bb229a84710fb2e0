"""``bimgame play``: people play the Ball-in-Maze Game or CyberRunner's labyrinth in a browser, watch a
trained agent or the MPC expert, take over from it, and have their play on the maze recorded as a
Minari dataset (README, "Playing in a browser").

- :mod:`~bimgame.play.controls` — keys to the envs' discrete actions, held keys of every client.
- :mod:`~bimgame.play.boards` — the maze's and the labyrinth's envs behind one interface.
- :mod:`~bimgame.play.agent` — a trained policy (greedy or sampled) or the MPC expert acting step by step.
- :mod:`~bimgame.play.session` — the game loop's state machine, independent of the web.
- :mod:`~bimgame.play.recording` — the person's episodes as a resumable Minari dataset directory.
- :mod:`~bimgame.play.minari_human` — the child process that builds that Minari dataset.
- :mod:`~bimgame.play.protocol` — the websocket messages, parsed and checked.
- :mod:`~bimgame.play.server` — the aiohttp application: the page, the websocket, the game loop
  (30 Hz on the maze, 55 Hz on the labyrinth).
"""
