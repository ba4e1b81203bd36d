#include "cip/core/progress_bar.h"

#include <unistd.h>

#include <algorithm>
#include <cstdio>

namespace cip {

ProgressBar::ProgressBar(std::string label, bool enabled)
    : label_(std::move(label)), active_(enabled && ::isatty(STDERR_FILENO)) {
  start_ = lastDraw_ = std::chrono::steady_clock::now();
}

ProgressBar::~ProgressBar() {
  finish();
}

void ProgressBar::update(double fraction) {
  if (!active_) return;
  std::lock_guard<std::mutex> lock(mutex_);
  if (finished_) return;
  auto now = std::chrono::steady_clock::now();
  if (fraction < 1.0 && now - lastDraw_ < std::chrono::milliseconds(100)) return;
  lastDraw_ = now;
  fraction = std::clamp(fraction, 0.0, 1.0);
  constexpr int kWidth = 30;
  int filled = static_cast<int>(fraction * kWidth);
  double seconds = std::chrono::duration<double>(now - start_).count();
  std::fprintf(stderr, "\r%-12s [%.*s%*s] %5.1f%%  %.1fs", label_.c_str(), filled,
               "##############################", kWidth - filled, "", 100.0 * fraction, seconds);
  std::fflush(stderr);
}

void ProgressBar::finish() {
  if (!active_) return;
  std::lock_guard<std::mutex> lock(mutex_);
  if (finished_) return;
  finished_ = true;
  std::fputc('\n', stderr);
}

}  // namespace cip
