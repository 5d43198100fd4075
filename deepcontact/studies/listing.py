"""The listing's side of `dc study`'s list (fence.py is dc's): run in the listing's sandbox, it
loads each installed study named and reports it on a pipe. Its own module, importing only what
loading a study needs: a listing is a fresh interpreter each time, and importing dc's side of
the fence with it (the job, the broker, the output rules) cost about 0.15 s of CPU each time."""
import json
import os

SUMMARY_MAX = 300   # characters of a summary in the list


def survey_here(fd, names):
    """In the listing's sandbox: each study named, loaded in turn, one line of JSON for it on the
    pipe fd as soon as it loads (its standard output is not the channel: a study that prints at
    import corrupts nothing); a summary is its first line, at most SUMMARY_MAX characters."""
    from . import _healthy
    from ..plugins import PluginError
    for name in names:
        try:
            s = _healthy(name)[0]
            entry = {"name": name, "summary": str(s.summary).strip().split("\n")[0][:SUMMARY_MAX],
                     "order": float(s.order), "writes": str(s.writes)}
        except PluginError as e:
            entry = {"name": name, "broken": str(e)[:SUMMARY_MAX * 4]}
        except Exception as e:   # (its own summary or order that is no text or number)
            entry = {"name": name, "broken": f"the study {name!r}: {type(e).__name__}: {e}"[:SUMMARY_MAX * 4]}
        os.write(fd, json.dumps(entry).encode() + b"\n")
