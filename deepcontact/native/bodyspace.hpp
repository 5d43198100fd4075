// A solve in body space (float64): the unknowns are the bodies' velocities, not the impulses.
//
// The step's problem as an augmented-Lagrangian fixed point. For multipliers lambda_k (the
// impulses of the last outer iteration) and a penalty rho per row (c over the row's effective
// inverse mass k, so rho has the units of a mass), the impulses are a function of the velocities:
//   normal:  ln(v) = max(0, ln_k - rho_n u_n(v))
//   tangent: lt(v) = clamp(lt_k - rho_t u_t(v), -mu ln(v), mu ln(v))
// with u = J v - bias the rows' velocities. The inner problem is Newton's method on the bodies'
// momentum balance g(v) = M (v - v*) - J^T lambda(v) = 0; its Jacobian M + J^T D J (D: -d lambda/du
// on the rows that touch or stick, and a sliding row's dependence on its normal) is regular
// however many contacts are redundant, and symmetric unless a point slides: Cholesky factorizes
// it then, a sparse LU otherwise. (Fixing the friction bounds per outer iteration, or dropping
// the sliding coupling, would make it Cholesky's always; neither converged on the settling pile:
// docs/solver.md.)
// An outer iteration sets lambda_k = lambda(v): at a fixed point every row is complementary and
// the step's LCP is solved.
//
// The outer iteration is a proximal point on the impulses, linear at a rate of about
// 1 / (1 + rho sigma) on a mode of the Delassus operator of eigenvalue sigma: a heavier penalty
// takes fewer outer iterations and more Newton iterations (a stiffer, more kinked inner problem),
// so c adapts. method_bodyspace.hpp's driver runs sweeps first and between failures, and counts every
// factorization, Newton iteration, outer iteration and fallback.
// Given a LaggedFactor (accelerate="lagged"), each Newton system is solved by BiCGSTAB
// preconditioned with that factor instead, and the factor made anew only when it no longer serves
// (lagged_factor.hpp).
#pragma once

#include <algorithm>
#include <cmath>
#include <limits>
#include <vector>

#include <Eigen/SparseCore>
#include <Eigen/SparseCholesky>
#include <Eigen/SparseLU>

#include "body_rows.hpp"
#include "contact_problem.hpp"
#include "lagged_factor.hpp"

namespace dc {

struct BodySpaceWork {
    int newton = 0;           // Newton iterations on the momentum balance
    int factorizations = 0;   // one per Newton iteration; with a lagged factor, as it is made anew
    int outer = 0;            // outer (multiplier) iterations
};

class BodySpace {
public:
    // penalty: the first c (rho = c / k per row), adapted as the outer iterations go; lagged: a
    // factor to precondition the Newton systems with (nullptr: each factorized exactly).
    BodySpace(ContactProblem<double>& pb, double scale, double penalty, LaggedFactor* lagged = nullptr)
        : pb_(pb), scale_(scale), c_(penalty), lagged_(lagged) {
        layout();
        if (lagged_) symmetric_ = H_;   // (H's pattern; its values are filled by assemble())
    }

    // One outer iteration from the impulses and velocities in the problem, whose residual is
    // `residual`; writes the new impulses and the velocities they give. The inner problem is
    // solved inexactly: to a tenth of the residual now (or of the tolerance, near the end), as an
    // inexact augmented Lagrangian may. false (nothing written, the penalty lightened) when its
    // Newton iterations do not get there.
    bool outer(double residual, double tolerance, BodySpaceWork& work) {
        if (points_.empty() || dofs_ == 0) return false;
        ++work.outer;
        read_multipliers();
        // v* from the velocities that go with the current impulses
        for (int d = 0; d < dofs_; ++d) v_[d] = velocity(d);
        body_impulse(lambda_k_, tmp_);
        for (int d = 0; d < dofs_; ++d) vstar_[d] = v_[d] - tmp_[d] / mass_[d];
        const double target = std::max(0.1 * std::max(tolerance, residual), 1e-15) * scale_;
        // (balance() leaves lambda_, y_ and largest_ at its v; a step taken keeps its trial's)
        double f = balance(v_, g_);
        for (int it = 0; it < kInnerLimit && largest_ > target; ++it) {
            assemble();
            ++work.newton;
            Eigen::Map<const Eigen::VectorXd> g(g_.data(), dofs_);
            Eigen::VectorXd dv;
            if (!direction(g, dv, work)) break;
            // Armijo on |g|^2_{M^-1}, halving
            bool accepted = false;
            for (double alpha = 1.0; alpha >= kSmallestStep; alpha *= 0.5) {
                for (int d = 0; d < dofs_; ++d) trial_[d] = v_[d] + alpha * dv[d];
                const double trial = balance(trial_, trial_g_);
                if (trial <= (1.0 - 1e-4 * alpha) * f) {
                    std::swap(v_, trial_);
                    std::swap(g_, trial_g_);
                    f = trial;
                    accepted = true;
                    break;
                }
            }
            if (!accepted) {
                balance(v_, g_);   // back to v_'s impulses from the last trial's
                break;
            }
        }
        if (largest_ > target) {  // the inner problem too stiff for Newton from here: a lighter penalty next time
            c_ = std::max(kLightest, c_ / kPenaltyStep);
            return false;
        }
        // lambda_{k+1} = lambda(v) (balance() left it); the velocities written are the ones these impulses give
        write();
        return true;
    }

    // The Newton direction, H dv = -g: by Cholesky (Eigen's SimplicialLDLT, about 4.7 times
    // cheaper here) where no point slides and H is symmetric, by a sparse LU where one does; with
    // a lagged factor, by BiCGSTAB preconditioned with it, made anew (from H's symmetric part) when
    // it no longer serves. false if the factorization fails.
    bool direction(const Eigen::Map<const Eigen::VectorXd>& g, Eigen::VectorXd& dv, BodySpaceWork& work) {
        if (lagged_) return lagged_direction(-g, dv, work);
        ++work.factorizations;
        return sliding_ ? solved(lu_, analyzed_lu_, g, dv) : solved(ldlt_, analyzed_ldlt_, g, dv);
    }

    // H dv = rhs by BiCGSTAB with the lagged factor; where that factor does not serve these
    // unknowns or BiCGSTAB does not get there, once more with a factor made from this system.
    bool lagged_direction(const Eigen::VectorXd& rhs, Eigen::VectorXd& dv, BodySpaceWork& work) {
        const size_t bodies = pb_.velocity.size();
        if (lagged_->serves(body_of_, bodies) && krylov_solve(H_, *lagged_, rhs, dv)) return true;
        ++work.factorizations;
        return lagged_->factorize(symmetric_, body_of_, bodies) && krylov_solve(H_, *lagged_, rhs, dv);
    }

    // H_ factorized by `solver` (its pattern analysed the first time), dv = -H^-1 g.
    template <class Solver>
    bool solved(Solver& solver, bool& analyzed, const Eigen::Map<const Eigen::VectorXd>& g, Eigen::VectorXd& dv) {
        if (!analyzed) {
            solver.analyzePattern(H_);
            analyzed = true;
        }
        solver.factorize(H_);
        if (solver.info() != Eigen::Success) return false;
        dv = solver.solve(-g);
        return dv.allFinite();
    }

    // The penalty c now (what the native loop carries to the next step for the lagged method).
    double penalty() const { return c_; }

    // After an outer iteration that lowered the residual from `before` to `after`: a slow one
    // (less than halved) stiffens the penalty, which speeds the outer iteration on the step's
    // soft modes and makes the inner problem harder.
    void progress(double before, double after) {
        if (after > 0.5 * before) c_ = std::min(kHeaviest, c_ * kPenaltyStep);
    }

private:
    static constexpr double kLightest = 1.0, kHeaviest = 1e5, kPenaltyStep = 4.0;
    static constexpr int kInnerLimit = 30;
    static constexpr double kSmallestStep = 1.0 / 64;

    struct Point {
        ContactManifold<double>* m;
        int j;
        int dof[6];          // the unknowns of (a vx, vy, w, b vx, vy, w); -1 where that body cannot move
        double jn[6], jt[6]; // the normal and tangent rows' Jacobians on those six velocities
        double kn, kt, bias, fixed_n, fixed_t;  // fixed_*: the rows' velocity from immovable dofs
        bool tangent;
        int pos[36];         // where H(dof[p], dof[q]) is stored
    };

    void layout() {
        const size_t nb = pb_.velocity.size();
        dof_of_.assign(3 * nb, -1);
        for (const auto& m : pb_.manifolds)
            for (int side = 0; side < 2; ++side) {
                const int body = side ? m.b : m.a;
                const double im = side ? m.mB : m.mA, ii = side ? m.iB : m.iA;
                for (int c = 0; c < 3; ++c)
                    if ((c < 2 ? im : ii) > 0 && dof_of_[3 * body + c] < 0) {
                        dof_of_[3 * body + c] = dofs_++;
                        body_of_.push_back(3 * body + c);
                        mass_.push_back(1.0 / (c < 2 ? im : ii));
                    }
            }
        const std::vector<BodyRow> rows = body_rows(pb_);
        for (auto& m : pb_.manifolds) {
            for (int j = 0; j < m.count; ++j) {
                const auto& p = m.p[j];
                Point q{};
                q.m = &m;
                q.j = j;
                q.tangent = m.friction_row;
                const double* jn = rows[m.first + j].normal;
                const double* jt = rows[m.first + j].tangent;
                for (int c = 0; c < 6; ++c) {
                    const int body = c < 3 ? m.a : m.b;
                    q.dof[c] = dof_of_[3 * body + c % 3];
                    q.jn[c] = jn[c];
                    q.jt[c] = jt[c];
                    if (q.dof[c] < 0) {  // (an immovable dof keeps its velocity: a constant of the row)
                        const auto& bv = pb_.velocity[body];
                        const double vel = c % 3 == 0 ? bv.v.x : c % 3 == 1 ? bv.v.y : bv.w;
                        q.fixed_n += jn[c] * vel;
                        q.fixed_t += jt[c] * vel;
                    }
                }
                // (a row no unknown moves has no penalty: c / infinity = 0 keeps its impulse)
                const double inf = std::numeric_limits<double>::infinity();
                q.kn = p.k_normal > 0 ? p.k_normal : inf;
                q.kt = p.k_tangent > 0 ? p.k_tangent : inf;
                q.bias = p.bias;
                points_.push_back(q);
            }
        }
        // The pattern of H: the mass diagonal and, per point, its two bodies' 6x6 block.
        std::vector<Eigen::Triplet<double>> pattern;
        for (int d = 0; d < dofs_; ++d) pattern.emplace_back(d, d, 0.0);
        for (const Point& q : points_)
            for (int r = 0; r < 6; ++r)
                for (int c = 0; c < 6; ++c)
                    if (q.dof[r] >= 0 && q.dof[c] >= 0) pattern.emplace_back(q.dof[r], q.dof[c], 0.0);
        H_.resize(dofs_, dofs_);
        H_.setFromTriplets(pattern.begin(), pattern.end());
        H_.makeCompressed();
        auto index = [&](int r, int c) {  // the stored entry (r, c) of the compressed H_
            const int* rows = H_.innerIndexPtr();
            const int* begin = rows + H_.outerIndexPtr()[c];
            const int* end = rows + H_.outerIndexPtr()[c + 1];
            return static_cast<int>(std::lower_bound(begin, end, r) - rows);
        };
        for (int d = 0; d < dofs_; ++d) diagonal_.push_back(index(d, d));
        for (Point& q : points_)
            for (int r = 0; r < 6; ++r)
                for (int c = 0; c < 6; ++c)
                    q.pos[6 * r + c] = q.dof[r] >= 0 && q.dof[c] >= 0 ? index(q.dof[r], q.dof[c]) : -1;
        v_.resize(dofs_);
        vstar_.resize(dofs_);
        g_.resize(dofs_);
        trial_.resize(dofs_);
        trial_g_.resize(dofs_);
        tmp_.resize(dofs_);
        lambda_k_.resize(2 * points_.size());
        lambda_.resize(2 * points_.size());
    }

    double velocity(int d) const {
        const int k = body_of_[d];
        const auto& bv = pb_.velocity[k / 3];
        return k % 3 == 0 ? bv.v.x : k % 3 == 1 ? bv.v.y : bv.w;
    }

    void read_multipliers() {
        for (size_t i = 0; i < points_.size(); ++i) {
            const auto& p = points_[i].m->p[points_[i].j];
            lambda_k_[2 * i] = p.normal_impulse;
            lambda_k_[2 * i + 1] = points_[i].tangent ? p.tangent_impulse : 0.0;
        }
    }

    // out = J^T lambda, on the unknowns
    void body_impulse(const std::vector<double>& lambda, std::vector<double>& out) const {
        std::fill(out.begin(), out.end(), 0.0);
        for (size_t i = 0; i < points_.size(); ++i) {
            const Point& q = points_[i];
            for (int c = 0; c < 6; ++c)
                if (q.dof[c] >= 0) out[q.dof[c]] += q.jn[c] * lambda[2 * i] + q.jt[c] * lambda[2 * i + 1];
        }
    }

    // The rows' velocities at v, and the impulses lambda(v); the penalty arguments y are kept
    // for the Jacobian.
    void multipliers(const std::vector<double>& v, std::vector<double>& lambda) {
        y_.resize(lambda.size());
        for (size_t i = 0; i < points_.size(); ++i) {
            const Point& q = points_[i];
            double un = q.fixed_n - q.bias, ut = q.fixed_t;
            for (int c = 0; c < 6; ++c)
                if (q.dof[c] >= 0) {
                    un += q.jn[c] * v[q.dof[c]];
                    ut += q.jt[c] * v[q.dof[c]];
                }
            const double yn = lambda_k_[2 * i] - (c_ / q.kn) * un;
            const double ln = std::max(yn, 0.0);
            y_[2 * i] = yn;
            lambda[2 * i] = ln;
            if (q.tangent) {
                const double yt = lambda_k_[2 * i + 1] - (c_ / q.kt) * ut;
                const double bound = q.m->friction * ln;
                y_[2 * i + 1] = yt;
                lambda[2 * i + 1] = std::clamp(yt, -bound, bound);
            } else {
                y_[2 * i + 1] = lambda[2 * i + 1] = 0.0;
            }
        }
    }

    // g = M (v - v*) - J^T lambda(v); returns |g|^2_{M^-1} and sets largest_ = max |g / m|.
    double balance(const std::vector<double>& v, std::vector<double>& g) {
        multipliers(v, lambda_);
        body_impulse(lambda_, tmp_);
        double sum = 0;
        largest_ = 0;
        for (int d = 0; d < dofs_; ++d) {
            g[d] = mass_[d] * (v[d] - vstar_[d]) - tmp_[d];
            sum += g[d] * g[d] / mass_[d];
            largest_ = std::max(largest_, std::abs(g[d]) / mass_[d]);
        }
        return sum;
    }

    // H = M + J^T D J at the branches of the last balance() (y_, lambda_); with a lagged factor
    // also its symmetric part (the sliding coupling left out), which that factor is made from.
    void assemble() {
        double* values = H_.valuePtr();
        double* sym = lagged_ ? symmetric_.valuePtr() : nullptr;
        std::fill(values, values + H_.nonZeros(), 0.0);
        for (int d = 0; d < dofs_; ++d) values[diagonal_[d]] = mass_[d];
        if (sym) std::copy(values, values + H_.nonZeros(), sym);
        sliding_ = false;
        for (size_t i = 0; i < points_.size(); ++i) {
            const Point& q = points_[i];
            const bool touching = y_[2 * i] > 0;
            const double rn = touching ? c_ / q.kn : 0.0;
            double rt = 0.0, coupling = 0.0;   // coupling: a sliding row's impulse follows its normal's
            if (q.tangent && touching) {
                const double yt = y_[2 * i + 1], bound = q.m->friction * std::max(y_[2 * i], 0.0);
                if (yt > -bound && yt < bound) rt = c_ / q.kt;
                else coupling = (yt > 0 ? 1.0 : -1.0) * q.m->friction * rn;
                sliding_ = sliding_ || coupling != 0.0;
            }
            if (rn == 0.0 && rt == 0.0) continue;
            add_point(q, rn, rt, coupling, values, sym);
        }
    }

    // One point's 6x6 block of J^T D J into H's values (and, without the coupling, sym's):
    // d(-J^T lambda)/dv, row r of J^T times d lambda / du times column c of J.
    static void add_point(const Point& q, double rn, double rt, double coupling, double* values, double* sym) {
        for (int r = 0; r < 6; ++r) {
            if (q.dof[r] < 0) continue;
            for (int c = 0; c < 6; ++c) {
                const int at = q.pos[6 * r + c];
                if (at < 0) continue;
                const double symmetric = rn * q.jn[r] * q.jn[c] + rt * q.jt[r] * q.jt[c];
                values[at] += symmetric + coupling * q.jt[r] * q.jn[c];
                if (sym) sym[at] += symmetric;
            }
        }
    }

    void write() {
        body_impulse(lambda_, tmp_);
        for (int d = 0; d < dofs_; ++d) {
            const int k = body_of_[d];
            auto& bv = pb_.velocity[k / 3];
            const double v = vstar_[d] + tmp_[d] / mass_[d];
            (k % 3 == 0 ? bv.v.x : k % 3 == 1 ? bv.v.y : bv.w) = v;
        }
        for (size_t i = 0; i < points_.size(); ++i) {
            auto& p = points_[i].m->p[points_[i].j];
            p.normal_impulse = lambda_[2 * i];
            p.tangent_impulse = lambda_[2 * i + 1];
        }
    }

    ContactProblem<double>& pb_;
    double scale_, c_;
    int dofs_ = 0;
    std::vector<int> dof_of_, body_of_, diagonal_;
    std::vector<double> mass_;
    std::vector<Point> points_;
    std::vector<double> v_, vstar_, g_, trial_, trial_g_, tmp_, lambda_k_, lambda_, y_;
    double largest_ = 0;
    Eigen::SparseMatrix<double> H_, symmetric_;   // symmetric_: with a lagged factor alone
    LaggedFactor* lagged_;
    bool sliding_ = false;   // the last assemble() coupled a sliding point: H is not symmetric
    Eigen::SimplicialLDLT<Eigen::SparseMatrix<double>> ldlt_;
    Eigen::SparseLU<Eigen::SparseMatrix<double>> lu_;
    bool analyzed_ldlt_ = false, analyzed_lu_ = false;
};

}  // namespace dc
