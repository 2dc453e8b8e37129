#pragma once
// A parallel loop over indices, the one pattern the stages use for
// independent work (the fitter's starts and predictions, the loop's
// refits): up to `threads` threads, the caller's among them, each taking
// the next index as soon as it is free, so a long item does not hold the
// short ones behind it. The order items start in is the index order.
//
// The helper threads are kept and reused (a process-wide pool that grows to
// the most helpers ever asked for at once): a fit asks for a helper on
// every Jacobian of a lone Levenberg-Marquardt run, thousands of times in a
// run, and starting a thread each time cost kernel time and a wake-up's
// latency (BENCHMARKS.md). Every call gets all the helpers it asks for
// (idle ones, else new ones), so nested loops run exactly as with threads
// of their own and cannot wait on each other.
#include <algorithm>
#include <cstddef>
#include <type_traits>

namespace dropfit {

namespace detail {
// Runs call(context, i) for every i in [0, n) on the caller's thread and
// `helpers` pooled threads (core/parallel.cpp).
void parallel_for_pooled(std::size_t n, int helpers, void (*call)(void*, std::size_t), void* context);
}  // namespace detail

// Calls fn(i) once for every i in [0, n) on min(threads, n) threads (at
// least one: the caller's). fn must not throw; catch inside it.
template <class Fn>
void parallel_for(std::size_t n, int threads, Fn&& fn) {
  const int count = std::max(1, static_cast<int>(std::min<std::size_t>(std::max(threads, 1), n)));
  if (count <= 1) {
    for (std::size_t i = 0; i < n; ++i) fn(i);
    return;
  }
  using F = std::remove_reference_t<Fn>;
  detail::parallel_for_pooled(
      n, count - 1, [](void* f, std::size_t i) { (*static_cast<F*>(f))(i); },
      const_cast<void*>(static_cast<const void*>(&fn)));
}

}  // namespace dropfit
