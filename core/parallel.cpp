// The pooled helper threads behind parallel_for (core/parallel.h).
#include "core/parallel.h"

#include <atomic>
#include <condition_variable>
#include <mutex>
#include <thread>
#include <vector>

namespace dropfit::detail {
namespace {

// One parallel_for call: its items, taken in index order by whichever
// thread is free, and the helpers still working on it.
struct Job {
  std::size_t n = 0;
  void (*call)(void*, std::size_t) = nullptr;
  void* context = nullptr;
  std::atomic<std::size_t> next{0};
  std::mutex mutex;
  std::condition_variable finished;
  int running = 0;  // helpers not yet done with this job (under mutex)

  void work() {
    for (std::size_t i; (i = next++) < n;) call(context, i);
  }
};

// A pooled thread: sleeps until given a job, works on it, and goes back
// to the pool's idle list.
struct Helper {
  std::mutex mutex;
  std::condition_variable wake;
  Job* job = nullptr;  // under mutex
};

class Pool {
 public:
  // Gives `job` to `count` helpers: idle ones first, new ones for the rest.
  void start(Job& job, int count) {
    {
      std::lock_guard<std::mutex> lk(job.mutex);
      job.running = count;
    }
    std::vector<Helper*> chosen;
    {
      std::lock_guard<std::mutex> lk(mutex_);
      for (int k = 0; k < count; ++k) {
        if (idle_.empty()) {
          auto* h = new Helper;  // lives as long as the process, as its thread does
          std::thread([this, h] { serve(h); }).detach();
          chosen.push_back(h);
        } else {
          chosen.push_back(idle_.back());
          idle_.pop_back();
        }
      }
    }
    for (Helper* h : chosen) {
      {
        std::lock_guard<std::mutex> lk(h->mutex);
        h->job = &job;
      }
      h->wake.notify_one();
    }
  }

 private:
  [[noreturn]] void serve(Helper* h) {
    for (;;) {
      Job* job = nullptr;
      {
        std::unique_lock<std::mutex> lk(h->mutex);
        h->wake.wait(lk, [h] { return h->job != nullptr; });
        job = h->job;
        h->job = nullptr;
      }
      job->work();
      {
        // Back on the idle list before the job is released: the caller's
        // next loop finds this helper instead of starting a thread.
        std::lock_guard<std::mutex> lk(mutex_);
        idle_.push_back(h);
      }
      // The job lives on its caller's stack until running reaches 0; it
      // is not touched after the unlock.
      std::lock_guard<std::mutex> lk(job->mutex);
      if (--job->running == 0) job->finished.notify_all();
    }
  }

  std::mutex mutex_;
  std::vector<Helper*> idle_;
};

Pool& pool() {
  // Never destroyed: its threads sleep until the process ends.
  static Pool* p = new Pool;
  return *p;
}

}  // namespace

void parallel_for_pooled(std::size_t n, int helpers, void (*call)(void*, std::size_t), void* context) {
  Job job;
  job.n = n;
  job.call = call;
  job.context = context;
  pool().start(job, helpers);
  job.work();
  std::unique_lock<std::mutex> lk(job.mutex);
  job.finished.wait(lk, [&] { return job.running == 0; });
}

}  // namespace dropfit::detail
