// SPH splatting of particles onto a regular grid: G(x) = sum_i W(|x - q_i|, h) a_i.
// Each particle visits only the nodes within h of it (its window of cells), so the cost is
// linear in the particles. Kernels are the 2D-normalised ones (they integrate to 1 over the
// disc of radius h); deepcontact/grid/kernels.py has the same formulas in numpy.
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>

#include <cmath>
#include <stdexcept>
#include <vector>

#include "pyarrays.hpp"

namespace dc {
namespace {

constexpr double kPi = 3.14159265358979323846;

enum Kernel { poly6 = 0, spiky = 1, cubic = 2, gaussian = 3 };

// W(r) for r < h, 0 beyond; the normalisation constants are worked out once per call.
class KernelWeight {
public:
    KernelWeight(int kernel, double h) : kernel_(kernel), h_(h), h2_(h * h) {
        switch (kernel) {
            case poly6: norm_ = 4.0 / (kPi * std::pow(h, 8)); break;
            case spiky: norm_ = 10.0 / (kPi * std::pow(h, 5)); break;
            case cubic: norm_ = 40.0 / (7.0 * kPi * h * h); break;  // Monaghan, smoothing length h/2
            case gaussian: {                                        // s = h/2, truncated at h
                const double s = 0.5 * h;
                inv_s2_ = 1.0 / (s * s);
                norm_ = 1.0 / (kPi * s * s * (1.0 - std::exp(-4.0)));
                break;
            }
            default: throw std::invalid_argument("unknown kernel");
        }
    }
    // r2: squared distance
    double operator()(double r2) const {
        if (r2 >= h2_) return 0.0;
        switch (kernel_) {
            case poly6: {
                const double d = h2_ - r2;
                return norm_ * d * d * d;
            }
            case spiky: {
                const double d = h_ - std::sqrt(r2);
                return norm_ * d * d * d;
            }
            case cubic: {
                const double q = 2.0 * std::sqrt(r2) / h_;
                const double t = 2.0 - q;
                return q < 1.0 ? norm_ * (1.0 - 1.5 * q * q + 0.75 * q * q * q) : norm_ * 0.25 * t * t * t;
            }
            default:
                return norm_ * std::exp(-r2 * inv_s2_);
        }
    }

private:
    int kernel_;
    double h_, h2_, norm_ = 0, inv_s2_ = 0;
};

py::array_t<float> splat(py::array_t<double, py::array::c_style | py::array::forcecast> points,
                         py::array_t<double, py::array::c_style | py::array::forcecast> values, double x0,
                         double y0, double cell, int nx, int ny, double h, int kernel, bool renormalize) {
    if (points.ndim() != 2 || points.shape(1) != 2) throw py::value_error("points must have shape (n, 2)");
    if (values.ndim() != 2 || values.shape(0) != points.shape(0))
        throw py::value_error("values must have shape (n, channels), one row per point");
    if (!(cell > 0) || !(h > 0) || nx < 1 || ny < 1) throw py::value_error("cell, h and the grid must be positive");
    if (kernel < 0 || kernel > 3) throw py::value_error("unknown kernel");
    const size_t n = static_cast<size_t>(points.shape(0));
    const size_t channels = static_cast<size_t>(values.shape(1));
    std::vector<double> grid(channels * static_cast<size_t>(nx) * ny, 0.0);
    const double* p = points.data();
    const double* v = values.data();
    {
        py::gil_scoped_release release;
        const int reach = static_cast<int>(std::ceil(h / cell));
        const KernelWeight weight(kernel, h);
        std::vector<double> w;
        std::vector<size_t> node;
        for (size_t i = 0; i < n; ++i) {
            const double px = p[2 * i], py = p[2 * i + 1];
            if (!std::isfinite(px) || !std::isfinite(py)) continue;  // the caller checks and reports
            const int cx = static_cast<int>(std::floor((px - x0) / cell));
            const int cy = static_cast<int>(std::floor((py - y0) / cell));
            w.clear();
            node.clear();
            double total = 0.0;
            for (int iy = std::max(0, cy - reach); iy <= std::min(ny - 1, cy + reach + 1); ++iy) {
                const double dy = y0 + iy * cell - py;
                for (int ix = std::max(0, cx - reach); ix <= std::min(nx - 1, cx + reach + 1); ++ix) {
                    const double dx = x0 + ix * cell - px;
                    const double wi = weight(dx * dx + dy * dy);
                    if (wi > 0.0) {
                        w.push_back(wi);
                        node.push_back(static_cast<size_t>(iy) * nx + ix);
                        total += wi;
                    }
                }
            }
            // Renormalised: the particle's weights sum to 1 over the nodes it reaches, so the
            // grid holds amounts and conserves the particle's total (as the thesis code did).
            const double scale = renormalize ? (total > 0.0 ? 1.0 / total : 0.0) : 1.0;
            for (size_t k = 0; k < w.size(); ++k) {
                const double wk = w[k] * scale;
                for (size_t c = 0; c < channels; ++c) grid[c * nx * ny + node[k]] += wk * v[i * channels + c];
            }
        }
    }
    py::array_t<float> out({static_cast<py::ssize_t>(channels), static_cast<py::ssize_t>(ny), static_cast<py::ssize_t>(nx)});
    float* o = out.mutable_data();
    for (size_t k = 0; k < grid.size(); ++k) o[k] = static_cast<float>(grid[k]);
    return out;
}

}  // namespace

void bind_grid(py::module_& m) {
    m.def("splat", &splat, py::arg("points"), py::arg("values"), py::arg("x0"), py::arg("y0"), py::arg("cell"),
          py::arg("nx"), py::arg("ny"), py::arg("h"), py::arg("kernel"), py::arg("renormalize"),
          "SPH splat: grid[c, iy, ix] = sum_i W(|node - q_i|, h) values[i, c] (weights renormalised per "
          "particle if asked). Node (ix, iy) is at (x0 + ix cell, y0 + iy cell).");
}

}  // namespace dc
