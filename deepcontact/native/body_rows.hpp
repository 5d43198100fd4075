// A step's contact rows in body space: per contact point, the normal row's and the tangent row's
// Jacobians on the six velocities of its two bodies (a's vx, vy, w, then b's), the tangent being
// cross(normal, 1) as the sweeps apply it. Derived once from the assembled problem; Newton's rows
// (newton.hpp), the body-space solve's points (bodyspace.hpp) and the Python side's J
// (contact_rows: solver/local.py) all read these.
#pragma once

#include <vector>

#include "contact_problem.hpp"

namespace dc {

struct BodyRow {
    double normal[6], tangent[6];
};

inline void fill_row(double* row, V2<double> d, V2<double> rA, V2<double> rB) {
    row[0] = -d.x;
    row[1] = -d.y;
    row[2] = -cross(rA, d);
    row[3] = d.x;
    row[4] = d.y;
    row[5] = cross(rB, d);
}

// Indexed by the caller's point row (m.first + j), every point given (dropped ones too).
inline std::vector<BodyRow> body_rows(const ContactProblem<double>& pb) {
    std::vector<BodyRow> rows(pb.points);
    for (const auto& m : pb.manifolds) {
        const V2<double> tangent = cross(m.normal, 1.0);
        for (int j = 0; j < m.given; ++j) {
            BodyRow& row = rows[m.first + j];
            fill_row(row.normal, m.normal, m.p[j].rA, m.p[j].rB);
            fill_row(row.tangent, tangent, m.p[j].rA, m.p[j].rB);
        }
    }
    return rows;
}

}  // namespace dc
