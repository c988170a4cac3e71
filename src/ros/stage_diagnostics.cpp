#include "embedded_calibration_stereo/ros/stage_diagnostics.h"

#include <algorithm>
#include <numeric>

namespace embedded_calibration_stereo {

namespace {

// The q-quantile (0..1) of a non-empty vector, nearest rank; sorts it.
double quantile(std::vector<double>& v, double q) {
  std::sort(v.begin(), v.end());
  const size_t rank = std::min(v.size() - 1, static_cast<size_t>(q * v.size()));
  return v[rank];
}

}  // namespace

StageDiagnostics::StageDiagnostics(ros::NodeHandle& nh, ros::NodeHandle& pnh, const std::string& task)
    : updater_(std::make_unique<diagnostic_updater::Updater>(nh, pnh, pnh.getNamespace())),
      window_start_(ros::WallTime::now()) {
  updater_->setHardwareID(task);
  updater_->add(task, this, &StageDiagnostics::report);
  timer_ = nh.createWallTimer(ros::WallDuration(1.0), [this](const ros::WallTimerEvent&) { updater_->update(); });
}

void StageDiagnostics::frameIn() {
  std::lock_guard<std::mutex> lock(mutex_);
  ++window_in_;
  ++total_in_;
}

void StageDiagnostics::framePublished(const ros::Time& stamp, double processing_ms) {
  // In double: a stamp decades off (from another node) would overflow ros::Duration, which throws.
  const double latency_ms = (ros::Time::now().toSec() - stamp.toSec()) * 1e3;
  std::lock_guard<std::mutex> lock(mutex_);
  ++window_out_;
  ++total_out_;
  latencies_ms_.push_back(latency_ms);
  processing_ms_.push_back(processing_ms);
}

bool StageDiagnostics::checkShared(const cv::Mat& view, const sensor_msgs::Image& msg) {
  if (view.data == msg.data.data()) return false;
  std::lock_guard<std::mutex> lock(mutex_);
  ++input_copies_;
  return true;
}

void StageDiagnostics::set(const std::string& key, const std::string& value) {
  std::lock_guard<std::mutex> lock(mutex_);
  values_[key] = value;
}

uint64_t StageDiagnostics::inputCopies() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return input_copies_;
}

void StageDiagnostics::report(diagnostic_updater::DiagnosticStatusWrapper& status) {
  std::vector<double> latencies, processing;
  uint64_t in, out, total_in, total_out, copies;
  std::map<std::string, std::string> values;
  double span;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    const ros::WallTime now = ros::WallTime::now();
    span = std::max((now - window_start_).toSec(), 1e-3);
    window_start_ = now;
    in = window_in_;
    out = window_out_;
    window_in_ = window_out_ = 0;
    latencies.swap(latencies_ms_);
    processing.swap(processing_ms_);
    total_in = total_in_;
    total_out = total_out_;
    copies = input_copies_;
    values = values_;
  }
  using diagnostic_msgs::DiagnosticStatus;
  const double in_hz = in / span, out_hz = out / span;
  if (copies > 0) {
    status.summaryf(DiagnosticStatus::WARN, "%llu input frames were copied by an encoding conversion",
                    static_cast<unsigned long long>(copies));
  } else if (in == 0) {
    status.summary(DiagnosticStatus::OK, "idle: no input frame in the last period");
  } else {
    status.summaryf(DiagnosticStatus::OK, "%.1f Hz in, %.1f Hz out", in_hz, out_hz);
  }
  status.add("input rate (Hz)", in_hz);
  status.add("output rate (Hz)", out_hz);
  status.add("input frames", total_in);
  status.add("output frames", total_out);
  status.add("input copies", copies);
  if (!latencies.empty()) {
    status.add("latency p50 (ms)", quantile(latencies, 0.5));
    status.add("latency p95 (ms)", quantile(latencies, 0.95));
    status.add("latency max (ms)", latencies.back());  // sorted by quantile()
    status.add("frame time mean (ms)",
               std::accumulate(processing.begin(), processing.end(), 0.0) / processing.size());
    status.add("frame time max (ms)", *std::max_element(processing.begin(), processing.end()));
  }
  for (const auto& kv : values) status.add(kv.first, kv.second);
}

}  // namespace embedded_calibration_stereo
