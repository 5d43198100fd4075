"""Choosing the over-relaxation w of PSOR for a scene from a few of its steps.

PSOR (PGS with each update scaled by w) reaches a tolerance in far fewer sweeps on the thesis
pile at w around 1.5-1.7, and in more above 1.8; the best w depends on the scene (a pyramid's
stacked boxes gain little). `--relaxation auto` solves the first few steps that plain PGS needs
more than a few sweeps for, from their own start, at every candidate w and keeps the w with the fewest median sweeps (the smaller
w on ties). Those trial solves are real work and are counted in the time of the steps they
happen in. The solver's guard (pgs.solve) still drops w to 1 within any solve that diverges.
"""
import numpy as np

from .methods import solve
from .settings import relaxation_unheld

CANDIDATES = (1.0, 1.1, 1.2, 1.3, 1.4, 1.5, 1.6, 1.7, 1.8, 1.9)
TRIAL_STEPS = 8
INFORMATIVE = 8    # sweeps: a trial step must need more than this at w = 1
RETUNE_EVERY = 50  # problems between trials once tuned: the best w drifts as a scene settles


def parse_relaxation(text):
    """'auto' or a float in (0, 2), for the CLI; raises ValueError with the reason."""
    if str(text).strip().lower() == "auto":
        return "auto"
    try:
        w = float(text)
    except ValueError:
        raise ValueError(f"relaxation must be a number in (0, 2) or auto, got {text!r}") from None
    if not (0.0 < w < 2.0):
        raise ValueError(f"relaxation must be in (0, 2) or auto, got {text}")
    unheld = relaxation_unheld(w)
    if unheld:
        raise ValueError(unheld)
    return w


def sweeps_by_w(problem, start_n, start_t, settings):
    """{w: sweeps to the settings' tolerance} for every candidate w, from the same start."""
    return {w: solve(problem, start_n, start_t, settings=settings.but(relaxation=w), final_residual=False).iterations
            for w in CANDIDATES}


def best_w(trials):
    """The candidate with the fewest median sweeps over the trials (a list of sweeps_by_w dicts)."""
    if not trials:
        return 1.0
    medians = {w: float(np.median([t[w] for t in trials])) for w in CANDIDATES}
    return min(CANDIDATES, key=lambda w: (medians[w], w))


class AutoRelaxation:
    """Tunes w on the first TRIAL_STEPS hard problems it is shown, then keeps trying one problem
    in every RETUNE_EVERY and follows the best w over the last TRIAL_STEPS trials."""

    def __init__(self, settings, trial_steps=TRIAL_STEPS, retune_every=RETUNE_EVERY):
        """settings: the SolveSettings each trial solves with (its w aside)."""
        self.settings = settings
        self.trial_steps, self.retune_every = trial_steps, retune_every
        self.trials = []
        self.seen = 0

    @property
    def tuned(self):
        return len(self.trials) >= self.trial_steps

    @property
    def w(self):
        return best_w(self.trials[-self.trial_steps:])

    def wants_trial(self):
        """Whether the next problem will be tried at every candidate (else it is solved at self.w)."""
        return self.settings.tolerance > 0 and (not self.tuned or (self.seen + 1) % self.retune_every == 0)

    def solved_without_trial(self):
        """Counts a problem solved at self.w elsewhere (the native loop), as __call__ would have."""
        self.seen += 1

    def __call__(self, problem, start_n, start_t):
        """The w to solve this problem with (trying every candidate on it while tuning)."""
        trying = self.wants_trial()
        self.seen += 1
        if trying:
            trial = sweeps_by_w(problem, start_n, start_t, self.settings)
            # a problem plain PGS solves in a few sweeps (the first touch of a falling body) is
            # not what relaxation is for, and says nothing about the settled scene to come
            if trial[1.0] > INFORMATIVE:
                self.trials.append(trial)
        return self.w
