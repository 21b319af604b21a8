#pragma once
/// \file work_queue.h
/// \brief Internal to RastSlam: the queue between two pipeline stages. Not installed.

#include <condition_variable>
#include <deque>
#include <mutex>
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

} // namespace slam_detail
} // namespace rast
} // namespace pcl
