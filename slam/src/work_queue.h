#pragma once
/// \file work_queue.h
/// \brief Internal to the slam module: the queue between two pipeline stages, and a
/// thread that runs the tasks queued to it. Not installed.

#include <condition_variable>
#include <deque>
#include <future>
#include <mutex>
#include <thread>
#include <utility>

namespace pcl {
namespace rast {
namespace slam_detail {

/// A FIFO handing work from one stage to the next: push() never blocks, pop() waits on a
/// condition variable (no polling) until an item arrives or the queue is closed and
/// empty.
template <typename T> class WorkQueue
{
public:
  void push(T item)
  {
    {
      std::lock_guard<std::mutex> lock(mutex_);
      items_.push_back(std::move(item));
    }
    cv_.notify_one();
  }
  /// \return false when the queue is closed and drained.
  bool pop(T& item)
  {
    std::unique_lock<std::mutex> lock(mutex_);
    cv_.wait(lock, [&] { return closed_ || !items_.empty(); });
    if (items_.empty())
      return false;
    item = std::move(items_.front());
    items_.pop_front();
    return true;
  }
  /// Items waiting.
  std::size_t size()
  {
    std::lock_guard<std::mutex> lock(mutex_);
    return items_.size();
  }
  void close()
  {
    {
      std::lock_guard<std::mutex> lock(mutex_);
      closed_ = true;
    }
    cv_.notify_all();
  }

private:
  std::mutex mutex_;
  std::condition_variable cv_;
  std::deque<T> items_;
  bool closed_ = false;
};

/// A thread of its own, running the tasks queued to it in order; started with the
/// object and kept, since a thread started per task begins its work late (about 1.4 ms
/// in bench_front_end). Destroying it runs what is queued, then joins.
template <typename R> struct TaskThread
{
  TaskThread()
      : thread([this] {
          for (std::packaged_task<R()> task; tasks.pop(task);) {
            task();
            task = {}; // lets go of what it held (e.g. a scan)
          }
        })
  {}
  ~TaskThread()
  {
    tasks.close(); // a task queued is still run
    thread.join();
  }
  /// \a work on this thread; its result, or its exception, through the future.
  template <typename F> std::future<R> run(F&& work)
  {
    std::packaged_task<R()> task(std::forward<F>(work));
    std::future<R> result = task.get_future();
    tasks.push(std::move(task));
    return result;
  }
  WorkQueue<std::packaged_task<R()>> tasks;
  std::thread thread; ///< after tasks: starts once the queue exists
};

} // namespace slam_detail
} // namespace rast
} // namespace pcl
