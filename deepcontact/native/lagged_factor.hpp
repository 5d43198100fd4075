// A factor kept from one Newton system to the next, and in the native loop from one step to the
// next: the body-space solve's lagged variant (accelerate="lagged") solves each Newton system by
// BiCGSTAB preconditioned with the Cholesky factor of an earlier system's symmetric part, and
// factorizes again only when that fails. Why it may pay: a settled pile's system changes little
// between Newton iterations and steps (docs/results/bodyspace.md, "Amortizing the body-space operator":
// 20-30 iterations to 1e-8 with a factor 1-16 steps old), and a Newton direction needs only a
// couple of digits.
#pragma once

#include <vector>

#include <Eigen/IterativeLinearSolvers>
#include <Eigen/SparseCholesky>
#include <Eigen/SparseCore>

namespace dc {

// A Newton direction's relative residual (inexact Newton; the line search keeps it honest), and the
// BiCGSTAB iterations before the factor is made anew. On the settled 1000-circle pile (steps 300,
// 500, 700 from Box2D's warm start) these were the fastest of tolerances 0.01-0.5 and 3-30
// iterations: a native LDLT costs about as much as a few iterations, so a factor that needs many
// is not worth keeping.
constexpr double kKrylovTolerance = 0.3;
constexpr int kKrylovMost = 6;

class LaggedFactor {
public:
    // Whether the factor serves a system over these unknowns (dofs[d]: 3 * body row + component,
    // of `bodies` bodies): the same set in any order, the order then mapped.
    bool serves(const std::vector<int>& dofs, size_t bodies) {
        if (!ready_ || bodies != bodies_ || dofs.size() != dofs_.size()) return false;
        if (dofs == dofs_) {
            to_factor_.clear();
            return true;
        }
        std::vector<int> at(3 * bodies, -1);
        for (size_t d = 0; d < dofs_.size(); ++d) at[dofs_[d]] = static_cast<int>(d);
        to_factor_.resize(dofs.size());
        for (size_t d = 0; d < dofs.size(); ++d)
            if ((to_factor_[d] = at[dofs[d]]) < 0) return false;
        return true;
    }

    // Factorizes the symmetric positive definite `sym` over the unknowns `dofs`. false if it fails.
    bool factorize(const Eigen::SparseMatrix<double>& sym, const std::vector<int>& dofs, size_t bodies) {
        ready_ = false;
        ldlt_.compute(sym);   // (the pattern changes with the contacts: analysed each time)
        if (ldlt_.info() != Eigen::Success) return false;
        dofs_ = dofs;
        bodies_ = bodies;
        to_factor_.clear();
        ready_ = true;
        return true;
    }

    // The factor's inverse applied to r, in the numbering serves() last mapped.
    Eigen::VectorXd apply(const Eigen::VectorXd& r) const {
        if (to_factor_.empty()) return ldlt_.solve(r);
        Eigen::VectorXd in(r.size());
        for (Eigen::Index d = 0; d < r.size(); ++d) in[to_factor_[d]] = r[d];
        const Eigen::VectorXd z = ldlt_.solve(in);
        Eigen::VectorXd out(r.size());
        for (Eigen::Index d = 0; d < r.size(); ++d) out[d] = z[to_factor_[d]];
        return out;
    }

    // The penalty the last solve ended with (0: none yet): the next step starts from it.
    double penalty() const { return penalty_; }
    void set_penalty(double c) { penalty_ = c; }

private:
    Eigen::SimplicialLDLT<Eigen::SparseMatrix<double>> ldlt_;
    std::vector<int> dofs_, to_factor_;
    size_t bodies_ = 0;
    bool ready_ = false;
    double penalty_ = 0.0;
};

// A LaggedFactor as Eigen's iterative solvers take a preconditioner (its compute is a no-op: the
// factor is made by the caller, when it no longer serves).
struct LaggedPreconditioner {
    const LaggedFactor* factor = nullptr;
    LaggedPreconditioner() = default;
    template <class M> explicit LaggedPreconditioner(const M&) {}
    template <class M> LaggedPreconditioner& analyzePattern(const M&) { return *this; }
    template <class M> LaggedPreconditioner& factorize(const M&) { return *this; }
    template <class M> LaggedPreconditioner& compute(const M&) { return *this; }
    template <class V> Eigen::VectorXd solve(const V& b) const { return factor->apply(b); }
    Eigen::ComputationInfo info() const { return Eigen::Success; }
};

// H x = b by BiCGSTAB from zero, preconditioned by `factor`, to kKrylovTolerance within
// kKrylovMost iterations; false if it does not get there.
inline bool krylov_solve(const Eigen::SparseMatrix<double>& H, const LaggedFactor& factor, const Eigen::VectorXd& b,
                         Eigen::VectorXd& x) {
    Eigen::BiCGSTAB<Eigen::SparseMatrix<double>, LaggedPreconditioner> solver;
    solver.preconditioner().factor = &factor;
    solver.setTolerance(kKrylovTolerance);
    solver.setMaxIterations(kKrylovMost);
    solver.compute(H);
    x = solver.solve(b);
    return solver.info() == Eigen::Success && x.allFinite();
}

}  // namespace dc
