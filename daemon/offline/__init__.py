"""Work beside the running daemon, never on its ``grassd run`` path: validation against real
captures, the paper's experiments, virtual captures, HTML reports and sweeps."""
