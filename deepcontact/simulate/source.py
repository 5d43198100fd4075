"""Where a simulation's scene comes from: a scene file or a built-in generator, per seed."""
import dataclasses
from pathlib import Path

from .. import arguments
from ..errors import InputError
from ..resources import BYTES_PER_BODY, check_memory
from ..scene.generators import GENERATORS, body_count, generate
from ..scene.xml import read_scene


@dataclasses.dataclass
class SceneSource:
    """Callable seed -> Scene (picklable, so worker processes can build their own)."""
    spec: str
    params: dict = dataclasses.field(default_factory=dict)
    steps: int = None
    velocity_iterations: int = None

    def __post_init__(self):
        arguments.path(self.spec, "spec")   # (a scene file's path or a generator's name)
        if self.steps is not None:
            arguments.whole(self.steps, "steps", 1)
        if self.velocity_iterations is not None:
            arguments.whole(self.velocity_iterations, "velocity_iterations")
        arguments.mapping(self.params, "params")
        self.is_file = Path(self.spec).is_file()
        if self.is_file:
            if self.params:
                raise InputError("--param is for generators; a scene file sets its values itself",
                                 self.spec)
            self._file_scene = read_scene(self.spec)
        elif self.spec not in GENERATORS:
            raise InputError(f"{self.spec!r} is neither a scene file nor a generator; generators: "
                             f"{', '.join(GENERATORS)}")
        if self.steps is not None and self.steps < 1:
            raise InputError(f"--steps must be at least 1, got {self.steps}")
        if self.velocity_iterations is not None and self.velocity_iterations < 0:
            raise InputError(f"--iterations must be >= 0, got {self.velocity_iterations}")

    def __call__(self, seed):
        if self.is_file:
            scene = dataclasses.replace(self._file_scene)
        else:
            scene = generate(self.spec, seed, self.params)
        if self.steps is not None:
            scene.steps = self.steps
            scene.events = [e for e in scene.events if e.step < self.steps]
        if self.velocity_iterations is not None:
            scene.solver = dataclasses.replace(scene.solver, velocity_iterations=self.velocity_iterations)
        return scene

    def check_memory(self, workers=1, max_memory=None):
        """Refuse scenes too large for max_memory GB (workers simulate at once), before making any."""
        bodies = len(self._file_scene.bodies) if self.is_file else body_count(self.spec, self.params)
        check_memory(bodies * BYTES_PER_BODY * workers, max_memory,
                     f"simulating {bodies:,} bodies{f' in {workers} workers' if workers > 1 else ''}")

    @property
    def label(self):
        return self.spec
