// Benchmark nodelet (bench/pipeline, part 3): replays a bag's stereo frames closed-loop into a
// rectify + disparity graph loaded in the same manager, and writes the throughput to a JSON file.
//
// Why a nodelet: in the same manager as the pipeline under test, its messages travel as shared
// pointers, as a camera driver nodelet's do in a deployed head, so the figure is the pipeline's
// own cost. A probe in another process adds the (de)serialisation and socket copies of two
// 360 kB images in and a 1.4 MB disparity out to every frame of both pipelines alike, which
// shrinks the measured difference between them.
//
// Parameters (private): bag (file), passes (times the bag is replayed, default 1: later passes
// are copies restamped after the previous pass, so that a run lasts long enough to average out
// the machine's slow spells), in_flight (stereo frames published and not yet answered by a
// disparity, default 1), warmup_frames (10, not measured), timeout (s, 1: a frame unanswered this
// long counts as dropped), result_file (written atomically when done).
// Topics (node namespace): publishes left|right/image_raw + camera_info, subscribes disparity
// (header only is read) and /diagnostics (our nodelets' "frame time mean (ms)").
// Threads: onInit loads the bag; a worker thread (thread_) publishes and waits; the disparity
// and diagnostics callbacks run on the manager's threads. mutex_ guards received_ and frame_ms_.
#include <diagnostic_msgs/DiagnosticArray.h>
#include <nodelet/nodelet.h>
#include <pluginlib/class_list_macros.hpp>
#include <ros/ros.h>
#include <rosbag/bag.h>
#include <rosbag/view.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/Image.h>
#include <stereo_msgs/DisparityImage.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstdio>
#include <fstream>
#include <map>
#include <mutex>
#include <thread>
#include <vector>

namespace embedded_calibration_stereo_bench {

namespace {

using Clock = std::chrono::steady_clock;

struct StereoFrame {
  sensor_msgs::ImageConstPtr left, right;
  sensor_msgs::CameraInfoConstPtr left_info, right_info;
  bool complete() const { return left && right && left_info && right_info; }
};

double ms(Clock::duration d) { return std::chrono::duration<double, std::milli>(d).count(); }

double percentile(std::vector<double> v, double q) {
  if (v.empty()) return -1;
  std::sort(v.begin(), v.end());
  return v[std::min(v.size() - 1, static_cast<size_t>(q * v.size()))];
}

}  // namespace

class ReplayFeeder : public nodelet::Nodelet {
 public:
  ~ReplayFeeder() override {
    // Subscribers first: a callback delivered during destruction would use the members below.
    disparity_sub_.shutdown();
    diagnostics_sub_.shutdown();
    stop_ = true;
    arrived_.notify_all();
    if (thread_.joinable()) thread_.join();
  }

 private:
  void onInit() override {
    ros::NodeHandle& nh = getNodeHandle();
    ros::NodeHandle& pnh = getPrivateNodeHandle();
    const std::string bag_file = pnh.param<std::string>("bag", "");
    in_flight_ = std::max(1, pnh.param("in_flight", 1));
    warmup_frames_ = std::max(0, pnh.param("warmup_frames", 10));
    timeout_ = std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(pnh.param("timeout", 1.0)));
    result_file_ = pnh.param<std::string>("result_file", "");
    if (bag_file.empty() || result_file_.empty())
      throw std::runtime_error("ReplayFeeder: parameters ~bag and ~result_file are required");
    loadBag(bag_file);
    repeatFrames(std::max(1, pnh.param("passes", 1)));
    if (frames_.size() <= static_cast<size_t>(warmup_frames_))
      throw std::runtime_error("ReplayFeeder: " + bag_file + " has too few complete stereo frames");

    left_pub_ = nh.advertise<sensor_msgs::Image>("left/image_raw", in_flight_ + 2);
    right_pub_ = nh.advertise<sensor_msgs::Image>("right/image_raw", in_flight_ + 2);
    left_info_pub_ = nh.advertise<sensor_msgs::CameraInfo>("left/camera_info", in_flight_ + 2);
    right_info_pub_ = nh.advertise<sensor_msgs::CameraInfo>("right/camera_info", in_flight_ + 2);
    disparity_sub_ = nh.subscribe("disparity", 10, &ReplayFeeder::disparityCb, this);
    diagnostics_sub_ = nh.subscribe("/diagnostics", 50, &ReplayFeeder::diagnosticsCb, this);
    thread_ = std::thread([this] { run(); });
  }

  void loadBag(const std::string& file) {
    rosbag::Bag bag(file, rosbag::bagmode::Read);
    std::map<uint64_t, StereoFrame> by_stamp;
    for (const rosbag::MessageInstance& m : rosbag::View(bag)) {
      const std::string& topic = m.getTopic();
      const bool left = topic.find("left/") != std::string::npos;
      if (auto image = m.instantiate<sensor_msgs::Image>()) {
        (left ? by_stamp[image->header.stamp.toNSec()].left : by_stamp[image->header.stamp.toNSec()].right) = image;
      } else if (auto info = m.instantiate<sensor_msgs::CameraInfo>()) {
        auto& frame = by_stamp[info->header.stamp.toNSec()];
        (left ? frame.left_info : frame.right_info) = info;
      }
    }
    for (const auto& entry : by_stamp)
      if (entry.second.complete()) frames_.push_back(entry.second);
  }

  // Appends passes - 1 copies of the loaded frames, each stamped one bag span (plus one frame
  // interval) after the previous pass.
  void repeatFrames(int passes) {
    if (frames_.size() < 2 || passes < 2) return;
    const size_t n = frames_.size();
    frames_.reserve(n * passes);  // no reallocation while the loop below reads frames_[i]
    const ros::Time first = frames_.front().left->header.stamp, last = frames_.back().left->header.stamp;
    const ros::Duration span = (last - first) + (last - first) * (1.0 / (n - 1));
    for (int pass = 1; pass < passes; ++pass)
      for (size_t i = 0; i < n; ++i) {
        const StereoFrame& f = frames_[i];
        const ros::Duration offset = span * pass;
        StereoFrame copy;
        copy.left = restamped(*f.left, offset);
        copy.right = restamped(*f.right, offset);
        copy.left_info = restamped(*f.left_info, offset);
        copy.right_info = restamped(*f.right_info, offset);
        frames_.push_back(copy);
      }
  }
  template <class M>
  static boost::shared_ptr<const M> restamped(const M& m, const ros::Duration& offset) {
    auto copy = boost::make_shared<M>(m);
    copy->header.stamp += offset;
    return copy;
  }

  void disparityCb(const stereo_msgs::DisparityImageConstPtr& msg) {
    const auto now = Clock::now();
    std::lock_guard<std::mutex> lock(mutex_);
    received_[msg->header.stamp.toNSec()] = now;
    arrived_.notify_all();
  }

  void diagnosticsCb(const diagnostic_msgs::DiagnosticArrayConstPtr& msg) {
    std::lock_guard<std::mutex> lock(mutex_);
    if (!measuring_) return;
    for (const auto& status : msg->status)
      for (const char* stage : {"rectifier", "disparity"})
        if (status.name.rfind(getNodeHandle().getNamespace().substr(1) + "/" + stage + ":", 0) == 0)
          for (const auto& kv : status.values)
            if (kv.key == "frame time mean (ms)") frame_ms_[stage].push_back(std::atof(kv.value.c_str()));
  }

  bool connected() const {
    return disparity_sub_.getNumPublishers() > 0 && left_pub_.getNumSubscribers() > 0 &&
           right_pub_.getNumSubscribers() > 0 && left_info_pub_.getNumSubscribers() > 0 &&
           right_info_pub_.getNumSubscribers() > 0;
  }

  void run() {
    // The lazy pipeline subscribes its inputs in a chain once we subscribe its output; there
    // is no event for "all connected", so this polls (a benchmark, not a test).
    const auto deadline = Clock::now() + std::chrono::seconds(30);
    while (!stop_ && !connected() && Clock::now() < deadline) std::this_thread::sleep_for(std::chrono::milliseconds(50));
    if (!connected()) {
      NODELET_ERROR("ReplayFeeder: the pipeline did not connect within 30 s");
      return;
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(500));  // let the chain settle

    std::map<uint64_t, Clock::time_point> sent;
    std::vector<uint64_t> in_flight;
    Clock::time_point measured_from;
    for (size_t i = 0; i < frames_.size() && !stop_; ++i) {
      {
        std::unique_lock<std::mutex> lock(mutex_);
        while (!stop_) {
          // Answered, or dropped: older than an answered frame (the pipelines answer in stamp
          // order: their synchronisers discard older incomplete frames) or past the timeout.
          const uint64_t newest = received_.empty() ? 0 : received_.rbegin()->first;
          const auto now = Clock::now();
          in_flight.erase(std::remove_if(in_flight.begin(), in_flight.end(),
                                         [&](uint64_t s) {
                                           return received_.count(s) || s < newest || now - sent[s] > timeout_;
                                         }),
                          in_flight.end());
          if (static_cast<int>(in_flight.size()) < in_flight_) break;
          arrived_.wait_for(lock, std::chrono::milliseconds(10));
        }
        if (i == static_cast<size_t>(warmup_frames_)) {
          measured_from = Clock::now();
          measuring_ = true;
        }
      }
      const StereoFrame& frame = frames_[i];
      left_info_pub_.publish(frame.left_info);
      right_info_pub_.publish(frame.right_info);
      left_pub_.publish(frame.left);
      right_pub_.publish(frame.right);
      const uint64_t stamp = frame.left->header.stamp.toNSec();
      sent[stamp] = Clock::now();
      in_flight.push_back(stamp);
    }
    std::unique_lock<std::mutex> lock(mutex_);
    arrived_.wait_for(lock, timeout_, [&] {
      return stop_ || std::all_of(in_flight.begin(), in_flight.end(), [&](uint64_t s) { return received_.count(s) > 0; });
    });
    measuring_ = false;
    if (stop_) return;
    writeResult(sent, measured_from);
  }

  void writeResult(const std::map<uint64_t, Clock::time_point>& sent, Clock::time_point measured_from) {
    std::vector<double> latencies;
    Clock::time_point end = measured_from;
    for (size_t i = warmup_frames_; i < frames_.size(); ++i) {
      const auto it = received_.find(frames_[i].left->header.stamp.toNSec());
      if (it == received_.end()) continue;
      latencies.push_back(ms(it->second - sent.at(it->first)));
      end = std::max(end, it->second);
    }
    const size_t offered = frames_.size() - warmup_frames_;
    const double seconds = ms(end - measured_from) / 1e3;
    const auto median_frame_ms = [this](const char* stage) { return percentile(frame_ms_[stage], 0.5); };
    double load = -1;
    std::ifstream("/proc/loadavg") >> load;
    const std::string tmp = result_file_ + ".tmp";
    {
      std::ofstream out(tmp);
      out << "{\"frames_offered\": " << offered << ", \"disparity_frames\": " << latencies.size()
          << ", \"dropped\": " << offered - latencies.size() << ", \"seconds\": " << seconds
          << ", \"fps\": " << (seconds > 0 ? latencies.size() / seconds : 0.0)
          << ", \"latency_ms\": {\"p50\": " << percentile(latencies, 0.5) << ", \"p95\": " << percentile(latencies, 0.95)
          << ", \"n\": " << latencies.size() << "}, \"in_flight\": " << in_flight_
          << ", \"frame_time_ms\": {\"rectifier\": " << median_frame_ms("rectifier")
          << ", \"disparity\": " << median_frame_ms("disparity") << "}, \"loadavg\": " << load << "}\n";
    }
    if (std::rename(tmp.c_str(), result_file_.c_str()) != 0) {
      NODELET_ERROR("ReplayFeeder: cannot write %s", result_file_.c_str());
      return;
    }
    NODELET_INFO("ReplayFeeder: %zu of %zu frames in %.2f s; result in %s", latencies.size(), offered, seconds,
                 result_file_.c_str());
  }

  std::vector<StereoFrame> frames_;  // the bag's complete stereo frames in stamp order (read-only once loaded)
  int in_flight_ = 1, warmup_frames_ = 10;
  Clock::duration timeout_{};
  std::string result_file_;
  ros::Publisher left_pub_, right_pub_, left_info_pub_, right_info_pub_;
  ros::Subscriber disparity_sub_, diagnostics_sub_;
  std::thread thread_;
  std::atomic<bool> stop_{false};

  std::mutex mutex_;
  std::condition_variable arrived_;
  std::map<uint64_t, Clock::time_point> received_;  // disparity stamp (ns) -> arrival
  std::map<std::string, std::vector<double>> frame_ms_;
  bool measuring_ = false;
};

}  // namespace embedded_calibration_stereo_bench

PLUGINLIB_EXPORT_CLASS(embedded_calibration_stereo_bench::ReplayFeeder, nodelet::Nodelet)
