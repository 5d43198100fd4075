// Lemke's complementary pivoting for the LCP  w = M z + q >= 0, z >= 0, z.w = 0  (float64).
//
// The revised form of solver/pivoting.py's dense tableau, with the same pivot rule: the basis
// inverse B^-1 (n x n) and B^-1 q are kept; an entering column is formed from M's sparse column
// (a step's friction LCP has 2% of its entries nonzero), so a pivot costs one rank-one update of
// B^-1 (n^2) instead of the tableau's 2 n^2, and no temporary arrays. The answer is read from a
// fresh sparse LU of the final basis rather than from the updated B^-1 q, which carries the
// rounding of every pivot.
#pragma once

#include <Eigen/SparseCore>
#include <Eigen/SparseLU>

#include <algorithm>
#include <cmath>
#include <vector>

#include "interrupt.hpp"

namespace dc {

struct LemkeResult {
    bool solved = false;   // false: ray termination or too many pivots
    int pivots = 0;
    std::vector<double> z;
};

// The basic variables' values B^-1 q from a fresh factorization of the basis B (columns e_j for
// w_j, -M[:, j] for z_j); rhs is kept where the factorization fails.
inline void refactorize(const std::vector<int>& basis, const std::vector<std::vector<std::pair<int, double>>>& mcol,
                        const double* q, std::vector<double>& rhs) {
    const int n = static_cast<int>(basis.size());
    std::vector<Eigen::Triplet<double>> t;
    for (int c = 0; c < n; ++c) {
        if (basis[c] < n) t.emplace_back(basis[c], c, 1.0);
        else for (const auto& [i, v] : mcol[basis[c] - n]) t.emplace_back(i, c, -v);
    }
    Eigen::SparseMatrix<double> B(n, n);
    B.setFromTriplets(t.begin(), t.end());
    B.makeCompressed();
    Eigen::SparseLU<Eigen::SparseMatrix<double>> lu;
    lu.compute(B);
    if (lu.info() != Eigen::Success) return;
    const Eigen::VectorXd x = lu.solve(Eigen::Map<const Eigen::VectorXd>(q, n));
    if (lu.info() != Eigen::Success || !x.allFinite()) return;
    for (int i = 0; i < n; ++i) rhs[i] = x[i];
}

// M: n x n, row-major. max_pivots: at most this many pivots after the first.
inline LemkeResult lemke(const double* M, const double* q, int n, int max_pivots) {
    LemkeResult out;
    out.z.assign(n, 0.0);
    if (n == 0 || *std::min_element(q, q + n) >= 0) {
        out.solved = true;
        return out;
    }
    // M's columns, sparse: the entering column of z_j is -B^-1 M[:, j]
    std::vector<std::vector<std::pair<int, double>>> mcol(n);
    for (int i = 0; i < n; ++i)
        for (int j = 0; j < n; ++j)
            if (M[size_t(i) * n + j] != 0.0) mcol[j].emplace_back(i, M[size_t(i) * n + j]);

    // variables: w_i = i, z_i = n + i, the artificial z0 = 2n
    const int z0 = 2 * n;
    std::vector<double> binv(size_t(n) * n, 0.0), rhs(q, q + n), column(n);
    for (int i = 0; i < n; ++i) binv[size_t(i) * n + i] = 1.0;
    std::vector<int> basis(n);
    for (int i = 0; i < n; ++i) basis[i] = i;
    double scale = 1.0;
    for (int i = 0; i < n; ++i) scale = std::max(scale, std::abs(q[i]));

    auto entering_column = [&](int var) {
        if (var < n) {
            for (int i = 0; i < n; ++i) column[i] = binv[size_t(i) * n + var];
        } else if (var < z0) {
            for (int i = 0; i < n; ++i) {
                double s = 0.0;
                const double* row = &binv[size_t(i) * n];
                for (const auto& [k, v] : mcol[var - n]) s += row[k] * v;
                column[i] = -s;
            }
        } else {
            for (int i = 0; i < n; ++i) {
                double s = 0.0;
                const double* row = &binv[size_t(i) * n];
                for (int k = 0; k < n; ++k) s += row[k];
                column[i] = -s;
            }
        }
    };
    auto pivot = [&](int r) {
        const double p = column[r];
        double* pivot_row = &binv[size_t(r) * n];
        for (int k = 0; k < n; ++k) pivot_row[k] /= p;
        rhs[r] /= p;
        for (int i = 0; i < n; ++i) {
            const double c = column[i];
            if (i == r || c == 0.0) continue;
            double* row = &binv[size_t(i) * n];
            for (int k = 0; k < n; ++k) row[k] -= c * pivot_row[k];
            rhs[i] -= c * rhs[r];
        }
    };

    int r = int(std::min_element(q, q + n) - q);
    entering_column(z0);
    pivot(r);
    int leaving = basis[r];
    basis[r] = z0;
    std::vector<int> rows, ties;
    for (out.pivots = 1; out.pivots <= max_pivots; ++out.pivots) {
        poll_signals();
        const int entering = leaving < n ? leaving + n : leaving - n;  // the complement
        entering_column(entering);
        double largest = 1.0;
        for (int i = 0; i < n; ++i) largest = std::max(largest, std::abs(column[i]));
        double best = INFINITY;
        rows.clear();
        for (int i = 0; i < n; ++i)
            if (column[i] > 1e-12 * largest) {
                rows.push_back(i);
                best = std::min(best, rhs[i] / column[i]);
            }
        if (rows.empty()) return out;   // a ray: Lemke cannot go on
        ties.clear();
        for (int i : rows)
            if (rhs[i] / column[i] <= best + 1e-12 * scale) ties.push_back(i);
        r = ties.front();
        for (int i : ties)   // z0 leaves whenever it can: that ends the path
            if (basis[i] == z0) {
                r = i;
                break;
            }
        pivot(r);
        leaving = basis[r];
        basis[r] = entering;
        if (leaving == z0) {
            refactorize(basis, mcol, q, rhs);
            for (int i = 0; i < n; ++i)
                if (basis[i] >= n && basis[i] < z0) out.z[basis[i] - n] = std::max(rhs[i], 0.0);
            out.solved = true;
            return out;
        }
    }
    return out;
}

}  // namespace dc
