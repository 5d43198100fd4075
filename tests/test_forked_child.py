"""A plug-in that forks, and whose child carries on out of its code (it would run the rest of the
command: a second report, a second swap), has the child ended where it leaves the plug-in
(plugins.guest). It was ended without a word; it is now said, in one line naming the plug-in, and
the command goes on as the parent's."""
import os
import textwrap

from conftest import dc_process

PLUGINS = textwrap.dedent('''
    import os

    import deepcontact as dc


    class Forks:
        """Box2D's warm start; on its first call it forks, and the child carries on."""

        def __init__(self):
            self.forked = False

        def __call__(self, ctx):
            if not self.forked:
                self.forked = True
                os.fork()
            return dc.StartValue(ctx.problem.start_normal, ctx.problem.start_tangent, {"predict": 0.0})


    class ForkingSweeps:
        """Plain sweeps; forks on its first solve, and the child carries on."""

        def __init__(self):
            self.forked = False

        def __call__(self, problem, normal, tangent, settings):
            if not self.forked:
                self.forked = True
                os.fork()
            s = dc.solve(problem, normal, tangent, tolerance=settings.tolerance,
                         max_iterations=settings.max_iterations, history=True)
            return dc.MethodResult(s.normal_impulse, s.tangent_impulse, s.measure("residual"))
''')


def test_a_plugins_forked_child_that_carries_on_is_said_naming_it(run, tmp_path):
    (tmp_path / "mods").mkdir()
    (tmp_path / "mods" / "forking_plugins.py").write_text(PLUGINS)
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(tmp_path / "mods"), os.environ.get("PYTHONPATH", "")]))
    # a start, fenced (its sandbox's child), and a solver method in dc's own process
    r = dc_process("evaluate", run, "--starts", "builtin,forking_plugins:Forks", "--no-plots", "-q", "-o",
                   tmp_path / "report", env=env, timeout=600)
    said = [line for line in r.stderr.splitlines() if "forked a process" in line]
    assert r.returncode == 0 and said, r.stderr[-2000:]
    # (said inside the contestant's sandbox, by dc's side of it: relayed under the variant's name)
    relayed = [line.split("] ", 1)[1] if line.startswith("[the variant ") else line for line in said]
    assert all(line.startswith("dc: the start 'forking_plugins:Forks' forked a process that carried on")
               for line in relayed), said
    assert (tmp_path / "report" / "report.md").is_file()
    r = dc_process("simulate", "pile", "--param", "count=10", "--param", "box=12", "--steps", "100", "--solver", "pgs",
                   "--tolerance", "1e-4", "--accelerate", "forking_plugins:ForkingSweeps", "-q", "-o", tmp_path / "run",
                   env=env, timeout=600)
    said = [line for line in r.stderr.splitlines() if "forked a process" in line]
    assert r.returncode == 0 and len(said) == 1, r.stderr[-2000:]
    assert said[0].startswith("dc: the solver method 'forking_plugins:ForkingSweeps' forked a process")
    assert dc_process("validate", tmp_path / "run").returncode == 0
