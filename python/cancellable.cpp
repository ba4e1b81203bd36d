#include "cancellable.h"

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <exception>
#include <mutex>
#include <optional>
#include <thread>

namespace py = pybind11;

namespace cip::python {

namespace {

/// Thrown inside the work by its progress report once the caller asked it to stop.
struct Cancelled : std::exception {
  const char* what() const noexcept override { return "cancelled"; }
};

/// What the worker and the calling thread share.
struct WorkState {
  std::mutex mutex;
  std::condition_variable finished;
  bool done = false;
  std::exception_ptr error;
  std::atomic<double> fraction{-1.0};
  std::atomic<bool> cancel{false};
};

}  // namespace

void runCancellable(const std::function<void(const ReportProgress&)>& work, const py::object& progress) {
  WorkState state;
  const ReportProgress report = [&state](double f) {
    if (state.cancel.load()) throw Cancelled();
    state.fraction.store(f);
  };
  std::thread worker([&] {
    try {
      work(report);
    } catch (...) {
      state.error = std::current_exception();
    }
    std::lock_guard<std::mutex> lock(state.mutex);
    state.done = true;
    state.finished.notify_all();
  });
  std::optional<py::error_already_set> pythonError;
  double reported = -1.0;
  for (bool done = false; !done;) {
    {
      py::gil_scoped_release release;
      std::unique_lock<std::mutex> lock(state.mutex);
      done = state.finished.wait_for(lock, std::chrono::milliseconds(20), [&] { return state.done; });
    }
    if (pythonError) continue;
    try {
      const double f = state.fraction.load();
      if (!progress.is_none() && f > reported) {
        reported = f;
        progress(f);
      }
      if (PyErr_CheckSignals() != 0) throw py::error_already_set();
    } catch (py::error_already_set& e) {
      pythonError.emplace(std::move(e));
      state.cancel.store(true);
    }
  }
  worker.join();
  if (pythonError) throw std::move(*pythonError);
  if (state.error) std::rethrow_exception(state.error);
  if (!progress.is_none() && reported < 1.0) progress(1.0);
}

}  // namespace cip::python
