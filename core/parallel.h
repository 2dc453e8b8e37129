#pragma once
// A parallel loop over indices, the one pattern the stages use for
// independent work (the fitter's starts and predictions, the loop's
// refits): up to `threads` threads, the caller's among them, each taking
// the next index as soon as it is free, so a long item does not hold the
// short ones behind it. The order items start in is the index order.
#include <algorithm>
#include <atomic>
#include <cstddef>
#include <thread>
#include <vector>

namespace dropfit {

// Calls fn(i) once for every i in [0, n) on min(threads, n) threads (at
// least one: the caller's). fn must not throw; catch inside it.
template <class Fn>
void parallel_for(std::size_t n, int threads, Fn&& fn) {
  std::atomic<std::size_t> next{0};
  auto worker = [&] {
    for (std::size_t i; (i = next++) < n;) fn(i);
  };
  const int count = std::max(1, std::min<int>(threads, static_cast<int>(n)));
  std::vector<std::thread> pool;
  for (int w = 1; w < count; ++w) pool.emplace_back(worker);
  worker();
  for (auto& t : pool) t.join();
}

}  // namespace dropfit
