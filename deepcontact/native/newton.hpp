// A global step for the contact problem: proximal semismooth Newton on its min-map (float64).
//
// Per contact point, in velocity units (w = A lambda + b, the rows' velocities after the impulses):
//   normal:  F_n = min(k_n ln, w_n)
//   tangent: F_t = k_t lt - clamp(k_t lt - w_t, -mu k_t ln, mu k_t ln)
// the functions whose largest |F| over the step's free-velocity scale is the residual PGS reports.
//
// At an iterate each row takes one branch of its min or clamp: a normal row is separating
// (ln = 0) or touching (w_n = 0), a tangent row sliding (lt = +-mu ln) or sticking (w_t = 0).
// Newton's step solves that piecewise-linear system: the fixed impulses are substituted into the
// touching and sticking rows (a sliding row follows its normal impulse), which leaves a sparse
// system in the touching and sticking impulses, K = J_F W (J P)_F^T (not symmetric where points
// slide), factorized by sparse LU.
//
// A resting pile's contacts are redundant (more rows than the bodies' degrees of freedom): K is
// singular and its solutions form a family, most of them outside the friction cone. So each step
// solves a proximal problem instead, w + rho (lambda - lambda0) in place of w, which has one
// solution near lambda0 (K + rho I is regular); its solution is accepted when the true merit
// (the sum of F^2) falls. rho adapts: a hundred times larger after a failure, ten times smaller
// after a success (large rho is a short, safe step; small rho is Newton's fast one).
#pragma once

#include <Eigen/SparseCore>
#include <Eigen/SparseLU>

#include <algorithm>
#include <cmath>
#include <vector>

#include "body_rows.hpp"
#include "contact_problem.hpp"

namespace dc {

class Newton {
public:
    // scale: the step's free-velocity scale (the residual's denominator).
    // iterative: solve each step's system by conjugate gradients instead of a factorization, with
    // sliding rows held at the current friction bound (which keeps the system symmetric):
    // PGS with subspace minimization (Silcowitz, Niebe and Erleben 2010), inexact but cheap.
    Newton(ContactProblem<double>& pb, double scale, bool iterative = false)
        : pb_(pb), scale_(scale), iterative_(iterative) {
        layout();
    }

    // One proximal Newton step from the impulses and velocities in the problem; false (nothing
    // changed) when no rho up to the heaviest lowers the merit.
    bool step() {
        if (rows_.empty()) return false;
        read(base_);
        velocities(base_, w_);
        const double merit0 = merit(base_, w_, 0.0);
        if (merit0 == 0.0) return false;
        for (double rel = rho_; rel <= kHeaviest; rel *= 100.0) {
            const double rho = rel * largest_k_;
            x_ = base_;
            wx_ = w_;
            for (int inner = 0; inner < kInnerSteps; ++inner) {
                const double m = merit(x_, wx_, rho);
                if (m <= kInnerTolerance * merit0) break;
                ++factorizations_;
                if (!direction(rho) || !line_search(rho, m)) break;
            }
            if (merit(x_, wx_, 0.0) < merit0) {
                write(x_);
                rho_ = std::max(kLightest, rel * 0.1);
                return true;
            }
        }
        rho_ = kLightest;
        return false;
    }

    int factorizations() const { return factorizations_; }

private:
    static constexpr double kLightest = 1e-10;  // rho, relative to the largest k of the step
    static constexpr double kHeaviest = 1e-1;
    static constexpr int kInnerSteps = 3;      // Newton steps on one proximal problem
    static constexpr double kInnerTolerance = 1e-4;  // its merit, relative to the true one at lambda0
    static constexpr double kSmallestStep = 1.0 / 64;
    static constexpr int kCgIterations = 50;
    static constexpr double kCgReduction = 0.1;

    // A row of the problem: its point, and its Jacobian on the two bodies (j[0..2] on a's vx, vy,
    // w; j[3..5] on b's), from the step's body rows.
    struct Row {
        ContactManifold<double>* m;
        int j;
        bool tangent;
        int normal;          // for a tangent row, the row of its point's normal impulse
        const double* jac;
        double k, bias;
    };

    void layout() {
        body_rows_ = body_rows(pb_);
        for (auto& m : pb_.manifolds) {
            for (int j = 0; j < m.count; ++j) {
                const auto& p = m.p[j];
                const BodyRow& jac = body_rows_[m.first + j];
                const int normal_row = static_cast<int>(rows_.size());
                rows_.push_back(Row{&m, j, false, -1, jac.normal, p.k_normal, p.bias});
                if (m.friction_row) rows_.push_back(Row{&m, j, true, normal_row, jac.tangent, p.k_tangent, 0.0});
            }
        }
        for (const Row& r : rows_) largest_k_ = std::max(largest_k_, r.k);
        if (!(largest_k_ > 0)) largest_k_ = 1.0;
        dv_.resize(3 * pb_.velocity.size());
    }

    double& impulse(const Row& r) const {
        auto& p = r.m->p[r.j];
        return r.tangent ? p.tangent_impulse : p.normal_impulse;
    }
    void read(std::vector<double>& x) const {
        x.resize(rows_.size());
        for (size_t i = 0; i < rows_.size(); ++i) x[i] = impulse(rows_[i]);
    }

    // dv_ = W J^T d: the bodies' velocity change of impulse changes d.
    template <class D>
    void body_change(D d) {
        std::fill(dv_.begin(), dv_.end(), 0.0);
        for (size_t i = 0; i < rows_.size(); ++i) {
            const double di = d(i);
            if (di == 0.0) continue;
            const Row& r = rows_[i];
            const auto& m = *r.m;
            for (int c = 0; c < 3; ++c) {
                dv_[3 * m.a + c] += (c < 2 ? m.mA : m.iA) * r.jac[c] * di;
                dv_[3 * m.b + c] += (c < 2 ? m.mB : m.iB) * r.jac[3 + c] * di;
            }
        }
    }

    // J_i dv_: row i's velocity change.
    double row_change(const Row& r) const {
        const double* da = &dv_[3 * r.m->a];
        const double* db = &dv_[3 * r.m->b];
        double s = 0;
        for (int c = 0; c < 3; ++c) s += r.jac[c] * da[c] + r.jac[3 + c] * db[c];
        return s;
    }

    // Row velocities w at impulses x, from the problem's velocities (which go with base_).
    void velocities(const std::vector<double>& x, std::vector<double>& w) {
        body_change([&](size_t i) { return x[i] - base_[i]; });
        w.resize(rows_.size());
        for (size_t i = 0; i < rows_.size(); ++i) {
            const Row& r = rows_[i];
            const auto& A = pb_.velocity[r.m->a];
            const auto& B = pb_.velocity[r.m->b];
            w[i] = r.jac[0] * A.v.x + r.jac[1] * A.v.y + r.jac[2] * A.w + r.jac[3] * B.v.x + r.jac[4] * B.v.y +
                   r.jac[5] * B.w - r.bias + row_change(r);
        }
    }

    // Row i's velocity in the proximal problem.
    double shifted(size_t i, const std::vector<double>& x, const std::vector<double>& w, double rho) const {
        return w[i] + rho * (x[i] - base_[i]);
    }

    // The min-map F of row i at impulses x, row velocities w, in the proximal problem rho.
    double value(size_t i, const std::vector<double>& x, const std::vector<double>& w, double rho) const {
        const Row& r = rows_[i];
        const double s = shifted(i, x, w, rho);
        if (!r.tangent) return std::min(r.k * x[i], s);
        const double hi = std::abs(r.m->friction * r.k * x[r.normal]);
        const double kt = r.k * x[i];
        return kt - std::clamp(kt - s, -hi, hi);
    }

    double merit(const std::vector<double>& x, const std::vector<double>& w, double rho) const {
        double sum = 0;
        for (size_t i = 0; i < rows_.size(); ++i) {
            const double f = value(i, x, w, rho) / scale_;
            sum += f * f;
        }
        return sum;
    }

    void project(std::vector<double>& x) const {
        for (size_t i = 0; i < rows_.size(); ++i)
            if (!rows_[i].tangent) x[i] = std::max(x[i], 0.0);
        for (size_t i = 0; i < rows_.size(); ++i)
            if (rows_[i].tangent) {
                const double bound = rows_[i].m->friction * x[rows_[i].normal];
                x[i] = std::clamp(x[i], -bound, bound);
            }
    }

    // Armijo on the proximal merit along delta_, projected onto the cone; moves x_ on success.
    bool line_search(double rho, double merit_now) {
        const size_t n = rows_.size();
        trial_.resize(n);
        for (double alpha = 1.0; alpha >= kSmallestStep; alpha *= 0.5) {
            for (size_t r = 0; r < n; ++r) trial_[r] = x_[r] + alpha * delta_[r];
            project(trial_);
            velocities(trial_, trial_w_);
            if (merit(trial_, trial_w_, rho) <= (1.0 - 1e-4 * alpha) * merit_now) {
                std::swap(x_, trial_);
                std::swap(wx_, trial_w_);
                return true;
            }
        }
        return false;
    }

    void write(const std::vector<double>& x) {
        body_change([&](size_t i) { return x[i] - base_[i]; });
        for (size_t b = 0; b < pb_.velocity.size(); ++b) {
            pb_.velocity[b].v.x += dv_[3 * b];
            pb_.velocity[b].v.y += dv_[3 * b + 1];
            pb_.velocity[b].w += dv_[3 * b + 2];
        }
        for (size_t i = 0; i < rows_.size(); ++i) impulse(rows_[i]) = x[i];
    }

    // The Newton direction delta_ of the proximal problem at x_ (row velocities wx_).
    bool direction(double rho) {
        const size_t n = rows_.size();
        // Each row's branch: free (an equation on its velocity) or fixed: delta = slope * delta of
        // its normal row (sliding) + constant.
        std::vector<int> free_index(n, -1);
        std::vector<double> slope(n, 0.0), constant(n, 0.0);
        int nf = 0;
        for (size_t i = 0; i < n; ++i) {
            const Row& r = rows_[i];
            const double x = x_[i], s = shifted(i, x_, wx_, rho);
            if (!r.tangent) {
                if (r.k * x <= s) constant[i] = -x;  // separating: ln -> 0
                else free_index[i] = nf++;
                continue;
            }
            const double mu = r.m->friction, ln = x_[r.normal], hi = mu * r.k * ln;
            const double u = r.k * x - s;
            if (u >= hi) {  // sliding at +mu ln
                slope[i] = iterative_ ? 0.0 : mu;
                constant[i] = -(x - mu * ln);
            } else if (u <= -hi) {
                slope[i] = iterative_ ? 0.0 : -mu;
                constant[i] = -(x + mu * ln);
            } else {
                free_index[i] = nf++;
            }
        }
        // delta = P delta_F + q; the fixed part q first (a sliding row follows a fixed normal too).
        std::vector<double> q(n, 0.0);
        for (size_t i = 0; i < n; ++i) {
            if (free_index[i] >= 0) continue;
            q[i] = constant[i];
            if (rows_[i].tangent && slope[i] != 0.0 && free_index[rows_[i].normal] < 0)
                q[i] += slope[i] * q[rows_[i].normal];
        }
        delta_.assign(n, 0.0);
        if (nf > 0 && iterative_) {
            if (!conjugate_gradients(free_index, q, nf, rho)) return false;
        } else if (nf > 0) {
            // K = J_F W G with G = J^T P: a free row's own column, plus slope times a sliding
            // row's column on its (free) normal's.
            const int nb3 = static_cast<int>(3 * pb_.velocity.size());
            std::vector<Eigen::Triplet<double>> g, jf;
            g.reserve(12 * n);
            jf.reserve(6 * nf);
            auto add = [&](std::vector<Eigen::Triplet<double>>& t, const Row& r, int col, double c, bool weighted) {
                const auto& m = *r.m;
                for (int k = 0; k < 3; ++k) {
                    const double wa = weighted ? (k < 2 ? m.mA : m.iA) : 1.0;
                    const double wb = weighted ? (k < 2 ? m.mB : m.iB) : 1.0;
                    if (wa * r.jac[k] != 0.0) t.emplace_back(3 * m.a + k, col, c * wa * r.jac[k]);
                    if (wb * r.jac[3 + k] != 0.0) t.emplace_back(3 * m.b + k, col, c * wb * r.jac[3 + k]);
                }
            };
            for (size_t i = 0; i < n; ++i) {
                const Row& r = rows_[i];
                if (free_index[i] >= 0) {
                    add(g, r, free_index[i], 1.0, true);
                    add(jf, r, free_index[i], 1.0, false);
                } else if (r.tangent && slope[i] != 0.0 && free_index[r.normal] >= 0) {
                    add(g, r, free_index[r.normal], slope[i], true);
                }
            }
            Eigen::SparseMatrix<double> G(nb3, nf), JT(nb3, nf);
            G.setFromTriplets(g.begin(), g.end());
            JT.setFromTriplets(jf.begin(), jf.end());
            Eigen::SparseMatrix<double> K = Eigen::SparseMatrix<double>(JT.transpose()) * G;
            for (int c = 0; c < nf; ++c) K.coeffRef(c, c) += rho;
            K.makeCompressed();
            body_change([&](size_t i) { return q[i]; });
            Eigen::VectorXd rhs(nf);
            for (size_t i = 0; i < n; ++i)
                if (free_index[i] >= 0) rhs[free_index[i]] = -shifted(i, x_, wx_, rho) - row_change(rows_[i]);
            lu_.analyzePattern(K);
            lu_.factorize(K);
            if (lu_.info() != Eigen::Success) return false;
            const Eigen::VectorXd x = lu_.solve(rhs);
            if (!x.allFinite()) return false;
            for (size_t i = 0; i < n; ++i)
                if (free_index[i] >= 0) delta_[i] = x[free_index[i]];
        }
        for (size_t i = 0; i < n; ++i) {
            if (free_index[i] >= 0) continue;
            delta_[i] = q[i];
            if (rows_[i].tangent && slope[i] != 0.0 && free_index[rows_[i].normal] >= 0)
                delta_[i] = slope[i] * delta_[rows_[i].normal] + constant[i];
        }
        return true;
    }

    // K delta_F = rhs by Jacobi-preconditioned conjugate gradients, K = J_F W J_F^T + rho I applied
    // through the bodies (each product costs about one sweep); stops at a tenth of the first
    // residual or kCgIterations. Writes the free rows of delta_.
    bool conjugate_gradients(const std::vector<int>& free_index, const std::vector<double>& q, int nf, double rho) {
        std::vector<size_t> row_of(nf);
        for (size_t i = 0; i < rows_.size(); ++i)
            if (free_index[i] >= 0) row_of[free_index[i]] = i;
        body_change([&](size_t i) { return q[i]; });
        std::vector<double> b(nf), x(nf, 0.0), r(nf), z(nf), p(nf), kp(nf), diag(nf);
        for (int f = 0; f < nf; ++f) {
            const size_t i = row_of[f];
            b[f] = -shifted(i, x_, wx_, rho) - row_change(rows_[i]);
            diag[f] = rows_[i].k + rho;
        }
        auto apply = [&](const std::vector<double>& v, std::vector<double>& out) {
            body_change([&](size_t i) { return free_index[i] >= 0 ? v[free_index[i]] : 0.0; });
            for (int f = 0; f < nf; ++f) out[f] = row_change(rows_[row_of[f]]) + rho * v[f];
        };
        r = b;
        double rz = 0, first = 0;
        for (int f = 0; f < nf; ++f) {
            z[f] = r[f] / diag[f];
            p[f] = z[f];
            rz += r[f] * z[f];
            first = std::max(first, std::abs(r[f]));
        }
        if (!(first > 0)) return true;
        for (int it = 0; it < kCgIterations; ++it) {
            apply(p, kp);
            double pkp = 0;
            for (int f = 0; f < nf; ++f) pkp += p[f] * kp[f];
            if (!(pkp > 0)) break;
            const double alpha = rz / pkp;
            double worst = 0, rz_next = 0;
            for (int f = 0; f < nf; ++f) {
                x[f] += alpha * p[f];
                r[f] -= alpha * kp[f];
                worst = std::max(worst, std::abs(r[f]));
                z[f] = r[f] / diag[f];
                rz_next += r[f] * z[f];
            }
            if (worst <= kCgReduction * first) break;
            const double beta = rz_next / rz;
            rz = rz_next;
            for (int f = 0; f < nf; ++f) p[f] = z[f] + beta * p[f];
        }
        for (int f = 0; f < nf; ++f) {
            if (!std::isfinite(x[f])) return false;
            delta_[row_of[f]] = x[f];
        }
        return true;
    }

    ContactProblem<double>& pb_;
    double scale_;
    bool iterative_ = false;
    double largest_k_ = 0.0;
    double rho_ = kLightest;
    int factorizations_ = 0;
    std::vector<BodyRow> body_rows_;
    std::vector<Row> rows_;
    std::vector<double> base_, w_, x_, wx_, trial_, trial_w_, delta_, dv_;
    Eigen::SparseLU<Eigen::SparseMatrix<double>> lu_;
};

}  // namespace dc
