"""Studies: longer measurements built on every floor below. `STUDIES` is the one table of them:
`dc study` takes its commands, their order and its help's list from it."""
from dataclasses import dataclass


@dataclass(frozen=True)
class Study:
    """One study: its `dc study` name, the module under deepcontact.studies that runs it, a line
    saying what it measures, and what its -o names: a folder (tables, CSV and plots), a file (its
    table) or a text report (also echoed to stdout as it comes)."""
    name: str
    module: str
    summary: str
    writes: str


STUDIES = (
    Study("stability", "stability", "the hard scenes under Box2D's solver and ours: the iterations each needs", "file"),
    Study("engines", "engines", "accuracy against time: Box2D 2.4.1, Box2D v3 and the project's solver", "folder"),
    Study("frontier", "frontier", "the same at scale: piles, confined circles and pyramids of thousands", "folder"),
    Study("figures", "figures", "the thesis's convergence figures 5.4-5.7, regenerated with the SPH start", "folder"),
    Study("maps", "maps", "one network for both impulse maps, or one per map", "folder"),
    Study("oracle", "sph_oracle", "the grid's own loss: exact impulses through the grid and back", "folder"),
    Study("learned-correction", "learned_correction", "a learned correction of Box2D's warm start on the contact graph",
          "text"),
    Study("learned-coarse", "learned_coarse", "a learned coarse space between sweeps", "text"),
    Study("relaxation", "relaxation", "time to the same accuracy: over-relaxation, NNCG, Newton, prev", "text"),
    Study("exact", "exact", "the reference solutions: time to 1e-12, pivots, the hard scenes", "text"),
    Study("peer", "peer", "our solver against Siconos (NSGS, Lemke) on the same problems", "text"),
    Study("amortize", "amortize", "what a factor reused across steps could buy on 1,000 and 10,000 circles", "folder"),
    Study("scale", "scale", "every method's time to 1e-4 as the pile grows (100 to 10,000 circles)", "text"),
    Study("global-families", "global_families", "ADMM and a cone augmented Lagrangian, as prototypes, against the "
          "solver's; where PGS stalls, and two second levels after it", "text"),
)
