#include "noise_debias_cache.hpp"

#include <deque>
#include <memory>
#include <mutex>
#include <utility>

namespace crfcal::detail {
namespace {

bool sameLaw(const NoiseDebiasOptions& a, const NoiseDebiasOptions& b) {
  return a.levels == b.levels && a.sigma == b.sigma && a.regularization == b.regularization &&
         a.regularizer == b.regularizer && a.sigma_per_level == b.sigma_per_level;
}

// A pair's fits see one or two noise laws (the fitter's and the effect search's, per channel); eight cover an RGB
// pair with room to spare, and bound the memory (two L×L matrices each: 1 MB at L = 256, 16 MB at L = 1024).
constexpr std::size_t kKeptLaws = 8;

}  // namespace

NoiseDebias cachedNoiseDebias(const NoiseDebiasOptions& options) {
  static std::mutex mutex;
  static std::deque<std::pair<NoiseDebiasOptions, std::shared_ptr<const NoiseDebias>>> kept;  // newest first
  {
    const std::lock_guard<std::mutex> lock(mutex);
    for (const auto& [law, op] : kept)
      if (sameLaw(law, options)) return *op;
  }
  // Built outside the lock: two threads meeting a new law may both build it (same result); one is kept.
  auto built = std::make_shared<const NoiseDebias>(options);
  const std::lock_guard<std::mutex> lock(mutex);
  kept.emplace_front(options, built);
  if (kept.size() > kKeptLaws) kept.pop_back();
  return *built;
}

}  // namespace crfcal::detail
