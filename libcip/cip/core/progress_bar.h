/// @file progress_bar.h
/// @brief A one-line progress bar on stderr for the command line tools; silent when disabled or when stderr
/// is not a terminal. Thread-safe: update() may be called from any thread.
#pragma once
#include <chrono>
#include <mutex>
#include <string>

namespace cip {

class ProgressBar {
 public:
  /// `enabled` = the user did not ask for quiet; the bar still stays silent when stderr is not a terminal.
  ProgressBar(std::string label, bool enabled);
  ~ProgressBar();
  /// Shows `fraction` (0..1) done; redraws at most every 100 ms.
  void update(double fraction);
  /// Completes the line (called by the destructor too).
  void finish();
  bool active() const { return active_; }

 private:
  std::string label_;
  bool active_;
  bool finished_ = false;
  std::mutex mutex_;
  std::chrono::steady_clock::time_point start_, lastDraw_;
};

}  // namespace cip
