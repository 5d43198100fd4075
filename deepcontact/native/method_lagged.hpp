// lagged: the solve in body space (method_bodyspace.hpp) with each Newton system solved by
// BiCGSTAB preconditioned with a factor made on an earlier system (lagged_factor.hpp). Within a
// step the factor serves every Newton and outer iteration it can; in the native loop (pgs_step)
// it is carried from step to step in the world, so a settled pile factorizes rarely, and with it
// the penalty the last step ended with, which the next starts from (on the settled 1000-circle
// pile: 29% fewer outer iterations than from c = 10 each step). A solve called alone (replay, the
// Python loop) starts without either.
#pragma once

#include "lagged_factor.hpp"
#include "method_bodyspace.hpp"

namespace dc {

inline void solve_lagged(Sweeps<double>& k, const SolveOptions& opt, SolveReport& rep, LaggedFactor* carried) {
    LaggedFactor own;
    solve_bodyspace(k, opt, rep, carried ? carried : &own);
}

}  // namespace dc
