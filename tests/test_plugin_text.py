"""A plug-in engine's text that XML cannot hold (its version() with a control character or a lone
surrogate, its name with one): the step writer's ValueError reached the user as the catch-all
("not a message of ours"), naming nothing, after the output folder was made. It is one line
naming the plug-in (as the user named it where dc runs it fenced), before any work."""
import textwrap

import pytest

import deepcontact as dc
from conftest import dc as invoke, one_line_error

PILE = ["pile", "--param", "count=5", "--param", "box=12", "--steps", "3", "-q"]

ENGINES = textwrap.dedent('''
    import deepcontact as dc


    class Ballistic(dc.Engine):
        """Bodies that stay where they are: an engine only to say things about itself."""
        name, label = "still", "still"
        VERSION = "1.0"

        @classmethod
        def version(cls):
            return cls.VERSION

        def build(self, scene, source=None):
            return Still(scene)

        def stepper(self, world, scene, record=True):
            def step():
                return dc.LoopStep(world.bodies() if record else None, dc.empty_contacts(0) if record else None)
            return step


    class Still:
        def __init__(self, scene):
            self.state = dc.scene_bodies(scene)

        def bodies(self):
            return {k: v.copy() for k, v in self.state.items()}

        def remove_body(self, index):
            kept = self.state["index"] != index
            self.state = {k: v[kept] for k, v in self.state.items()}


    class ControlVersion(Ballistic):
        VERSION = "1.0\\x01beta"


    class SurrogateVersion(Ballistic):
        VERSION = "1.0\\ud800"


    class ControlName(Ballistic):
        name = "still\\x02"
''')


@pytest.fixture
def engines(tmp_path, monkeypatch):
    (tmp_path / "mods").mkdir()
    (tmp_path / "mods" / "talking_engines.py").write_text(ENGINES)
    monkeypatch.syspath_prepend(str(tmp_path / "mods"))
    import importlib
    import talking_engines
    return importlib.reload(talking_engines)


@pytest.mark.parametrize("engine, said", [("ControlVersion", "its version() returned '1.0\\x01beta'"),
                                          ("SurrogateVersion", "its version() returned '1.0\\ud800'"),
                                          ("ControlName", "the engine's name is 'still\\x02'")])
def test_a_plugin_engines_text_xml_cannot_hold_is_one_line_naming_it(engines, tmp_path, engine, said):
    r = invoke("simulate", *PILE, "--engine", f"talking_engines:{engine}", "-o", tmp_path / "fenced")
    line = one_line_error(r, f"the engine 'talking_engines:{engine}'", said)
    assert "not a message of ours" not in line and not (tmp_path / "fenced").exists()
    with pytest.raises(dc.InputError, match="XML cannot"):   # (in a caller's process: the same words)
        dc.simulate_run(dc.SceneSource("pile", {"count": "5", "box": "12"}, steps=3), [0], tmp_path / "here",
                        engine=getattr(engines, engine)())
    assert not (tmp_path / "here").exists()
    assert invoke("simulate", *PILE, "--engine", "talking_engines:Ballistic", "-o", tmp_path / "ok").returncode == 0
