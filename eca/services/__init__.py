"""eca's processes and tools, around the models in agent/ and the wire in protocol/.

- `processes/`: the long-running processes on the bus (broker, dialogue, gaze, audio, renderer, web), each
  started as `python -m eca.services.processes.run NAME`, and what only they share (the `Service` loop, heartbeats,
  the dialogue state on disk);
- `tools/`: what a person runs: the `eca` command line (`cli.py`, one module per subcommand in `commands/`),
  the supervisor behind `eca up`, script playback and bus recordings, the offline renderer and the experiment;
- `pipecat/`: eca as the face of a pipecat bot, a library that lives in the bot's own process.

Imports go tools -> processes and pipecat -> tools, processes; never from processes to the others.
"""
