// Cancelling a build from its progress callback (what the Python module does on Ctrl-C): the exception the
// callback throws comes out of buildModel as it was thrown, through the builder's TBB arena and parallel
// loops, from any pass that reports progress, with any number of threads; nothing leaks (the sanitizer build
// checks), and the next build gives the same model as an uninterrupted one.
#include <gtest/gtest.h>

#include "cip/model/model_builder.h"
#include "cip/model/model_file.h"
#include "cip/volume/analytic_field.h"
#include "support/model_bytes.h"
#include "support/sanitized_build.h"

using namespace cip;

namespace {

struct Stop {
  double at;
};

}  // namespace

TEST(BuildCancel, AnExceptionFromProgressStopsTheBuild) {
  auto field = makeAnalyticField("gyroid");
  // N = 24 under the sanitizers (about 5,000 cells): every pass still reports its progress many times.
  const DenseGrid grid = sampleField(*field, test::kSanitizedBuild ? 24 : 40, "gyroid");
  BuildOptions options;
  options.isovalue = field->defaultIsovalue();
  const std::vector<std::uint8_t> whole = test::modelBytes(buildModel(grid, options));
  for (int threads : {1, 2}) {
    for (double stopAt : {0.0, 0.2, 0.6, 1.0}) {
      BuildOptions cancelled = options;
      cancelled.threads = threads;
      cancelled.progress = [stopAt](double f) {
        if (f >= stopAt) throw Stop{f};
      };
      try {
        buildModel(grid, cancelled);
        FAIL() << "the build went on after its progress callback threw";
      } catch (const Stop& stop) {
        EXPECT_GE(stop.at, stopAt);
      }
      options.threads = threads;
      EXPECT_EQ(test::modelBytes(buildModel(grid, options)), whole) << threads << " threads";
    }
  }
}
