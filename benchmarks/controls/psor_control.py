"""The honest over-relaxing control: a plug-in solver method that runs projected SOR at w = 1.7.

Used by the check of the verdict's power (docs/results/warm-starts.md): named on the command line as
`--accelerate none,psor_control:PSOR` with this folder on PYTHONPATH, it runs in the contestant's
sandbox like any plug-in and does honestly what builtin@1.7 does, through the public API: the
project's own native sweeps at w = 1.7, returning the impulses and the residual after each sweep.
"""
import deepcontact as dc


class PSOR:
    """Projected SOR at a fixed w (the native solve, its guard on), to the settings' tolerance and cap."""

    relaxation = 1.7

    def __call__(self, problem, start_normal, start_tangent, settings):
        # (a plug-in's settings name the plug-in and no w: ask the native sweeps for w = 1.7)
        sweeps = settings.but(accelerate="none", relaxation=self.relaxation)
        solution = dc.solve(problem, start_normal, start_tangent, settings=sweeps, history=True)
        return dc.MethodResult(solution.normal_impulse, solution.tangent_impulse, solution.measure("residual"))
