// Stop signals reach the native loops. A solve with the GIL released runs no Python, so Python's
// signal handlers (dc's raise Terminated; plain Python's, KeyboardInterrupt) would wait for it to
// end, hours for a cap of 2^31 sweeps. Every loop that can run long calls poll_signals() once an
// iteration: about every 50 ms it takes the GIL and runs the pending handlers, and if one raised,
// throws Interrupted, which unwinds the loop and reaches Python as the exception the handler
// raised (module.cpp's translator).
#pragma once

#include <chrono>

namespace dc {

// Not a std::exception: no catch (const std::exception&) on the way can take it for an error.
struct Interrupted {};

// Runs Python's pending signal handlers (main thread only); throws Interrupted if one raised.
// Defined in module.cpp, the one file that owns the interpreter's side.
void check_signals();

inline void poll_signals() {
    thread_local unsigned calls = 0;
    thread_local auto last = std::chrono::steady_clock::now();
    if (++calls % 16 != 0) return;  // (the clock is read every 16th call: a sweep can take microseconds)
    const auto now = std::chrono::steady_clock::now();
    if (now - last < std::chrono::milliseconds(50)) return;
    last = now;
    check_signals();
}

}  // namespace dc
