"""What a person runs: the `eca` command line and what its commands drive.

`cli.py` is the console script; `commands/` holds one subcommand per module and `cli_args.py` their argument
types. `up.py`, `supervisor.py` and `bus_view.py` are `eca up` (start, watch and restart the processes);
`child_processes.py` runs eca commands as children and reads their output; `playback.py`,
`script_input.py` and `recording.py` replay scripts onto the bus and record it; `offline.py`,
`offline_conversation.py` and `experiment.py` render scripts without a bus, frame by frame.
"""
