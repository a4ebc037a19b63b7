// Fork-join over a few threads: the processes run on one or two cores, so a pool per call
// (tens of microseconds) is cheap next to the work it splits.
#pragma once

#include <thread>
#include <vector>

namespace radslam {

/// Runs body(k) for k = 0 .. threads - 1, k = 0 on the calling thread, and returns when all
/// are done. threads < 2 runs body(0) alone.
template <class Body>
void runOnThreads(int threads, const Body& body) {
  std::vector<std::thread> pool;
  for (int k = 1; k < threads; ++k) pool.emplace_back([&body, k] { body(k); });
  body(0);
  for (std::thread& th : pool) th.join();
}

}  // namespace radslam
