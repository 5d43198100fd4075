// Checked access to dicts of numpy arrays handed over from Python.
#pragma once

#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>

#include <string>

namespace dc {
namespace py = pybind11;

// A column of a dict of arrays, checked: exact dtype, C order, n rows of `width` values.
template <typename T>
inline const T* column(const py::dict& d, const char* key, size_t& n, size_t width = 1) {
    if (!d.contains(key)) throw py::key_error(std::string("missing array '") + key + "'");
    py::object obj = d[key];
    if (!py::isinstance<py::array>(obj)) throw py::type_error(std::string("'") + key + "' must be a numpy array");
    py::array a = py::reinterpret_borrow<py::array>(obj);
    // equal(), not is(): an equivalent dtype object (from a pickle, say) is the same dtype
    if (!a.dtype().equal(py::dtype::of<T>()))
        throw py::type_error(std::string("'") + key + "' has dtype " + std::string(py::str(a.dtype())) +
                             ", expected " + std::string(py::str(py::dtype::of<T>())));
    if (!(a.flags() & py::array::c_style)) throw py::value_error(std::string("'") + key + "' must be C-contiguous");
    const size_t rows = a.ndim() == 0 ? 0 : static_cast<size_t>(a.shape(0));
    const bool shape_ok = width == 1 ? a.ndim() == 1 : (a.ndim() == 2 && a.shape(1) == static_cast<py::ssize_t>(width));
    if (!shape_ok) throw py::value_error(std::string("'") + key + "' has the wrong shape");
    if (n == static_cast<size_t>(-1)) n = rows;
    if (rows != n) throw py::value_error(std::string("'") + key + "' has " + std::to_string(rows) + " rows, expected " + std::to_string(n));
    return static_cast<const T*>(a.data());
}


void bind_solver(py::module_& m);
void bind_grid(py::module_& m);

}  // namespace dc
