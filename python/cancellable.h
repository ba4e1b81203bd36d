/// @file cancellable.h
/// @brief Running long C++ work from Python: off the interpreter's lock, with progress reports and Ctrl-C.
///
/// The work runs on a worker thread with the GIL released, so other Python threads go on meanwhile. The
/// calling thread keeps the GIL's ownership turns short: every 20 ms it wakes, hands the latest fraction the
/// work reported to the Python `progress` callable (on the calling thread, so the callable needs no locking)
/// and checks for signals, which is where Ctrl-C becomes KeyboardInterrupt. An exception from either cancels
/// the work: the work's next progress report throws, the exception unwinds the C++ work (TBB passes it out
/// of its parallel loops and arenas), the worker thread is joined, and the Python exception is raised. The
/// work is never abandoned half-way with threads still running.
#pragma once
#include <pybind11/pybind11.h>

#include <functional>

namespace cip::python {

/// What the work calls with its fraction done (0..1); throws when the work is to stop.
using ReportProgress = std::function<void(double)>;

/// Runs `work(report)` as described above. `progress` is None or a callable taking a float. C++ exceptions of
/// the work propagate as they are (pybind11 translates them); Python exceptions of the callback or the signal
/// handlers propagate instead when they came first.
void runCancellable(const std::function<void(const ReportProgress&)>& work, const pybind11::object& progress);

}  // namespace cip::python
