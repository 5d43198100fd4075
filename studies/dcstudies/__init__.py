"""The project's studies (`dc study`): the hard scenes' stability, what accuracy costs across
engines and at scale, the thesis's figures, the reference solutions and their peer. Each is a
module here with its command in commands.py, registered through this distribution's entry points."""
