// rostest: fuzzing the whole head (graph_fuzz.test). Beside the driver's own frames, this node
// publishes copies of the graph's input messages with random fields corrupted, from a fixed
// seed, for a bounded number of rounds and time, on every input topic:
//   left|right/image_raw, calibration_mode (tracker, separator, health, calibrator),
//   left|right/camera_info (rectifier, disparity, health, calibrator), calibration/observations
//   (calibrator, health), calibration/window_observations (calibrator), left|right/image_scene
//   (rectifier), left|right/image_rect (disparity), disparity_coverage (health),
//   and the driver's left|right/set_camera_info.
// A round publishes either one message on a random topic or a whole set of one consumer under
// one stamp (so that corrupted sets pass the synchronisers and reach the nodelets' code):
// images + mode, images + camera_info, mode + observations; or a burst of calibration_mode
// stamped ahead within the stamp tolerance; or a set_camera_info of the calibration in force
// with a principal point moved (off the image, or cx' alone: half a pair), a focal length far
// from the device's, or random corruptions. CameraInfos also get principal points far off the
// image. Stamps: the driver's latest, near it, ahead within the tolerance, far ahead, far
// behind, zero or the largest.
// Before: a 3 % zoom is committed, so that calibration files exist. After: the manager still
// runs and answers, disparity flows, the calibrator answers a request, and the calibration files
// parse (camera_calibration_parsers) as a consistent stereo pair (one image size, one fx', fy'
// and cy' in both P, the right Tx = -fx' * baseline < 0) equal to what the driver publishes.
#include <camera_calibration_parsers/parse.h>
#include <gtest/gtest.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/Image.h>
#include <stereo_msgs/DisparityImage.h>

#include <atomic>
#include <cmath>
#include <cstdio>
#include <limits>
#include <mutex>
#include <string>
#include <random>
#include <set>

#include <sensor_msgs/SetCameraInfo.h>

#include "driver_test_utils.h"
#include "embedded_calibration_stereo/CalibrationMode.h"
#include "embedded_calibration_stereo/CalibrationStatus.h"
#include "embedded_calibration_stereo/DisparityCoverage.h"
#include "embedded_calibration_stereo/Recalibrate.h"
#include "embedded_calibration_stereo/SetRigDrift.h"
#include "embedded_calibration_stereo/StereoPatternObservation.h"
#include "process_test_utils.h"

namespace test_support = embedded_calibration_stereo::test_support;

using embedded_calibration_stereo::BoardObservation;
using embedded_calibration_stereo::CalibrationMode;
using embedded_calibration_stereo::CalibrationStatus;
using embedded_calibration_stereo::Recalibrate;
using embedded_calibration_stereo::StereoPatternObservation;
using test_support::Collector;
using sensor_msgs::CameraInfo;
using sensor_msgs::Image;

namespace {

constexpr unsigned kSeed = 20240607;
constexpr int kRounds = 800;           // at most, and
constexpr double kFuzzSeconds = 25.0;  // at most
constexpr double kRoundPeriodS = 0.03;
constexpr double kFramePeriodS = 1.0 / 15;

// The latest message of a topic from another node than this one (the driver's or a nodelet's):
// the bases of the corrupted copies.
template <class M>
class Latest {
 public:
  Latest(ros::NodeHandle& nh, const std::string& topic) : sub_(nh.subscribe(topic, 2, &Latest::add, this)) {}
  ~Latest() { sub_.shutdown(); }
  typename M::ConstPtr get() {
    std::lock_guard<std::mutex> lock(mutex_);
    return latest_;
  }

 private:
  void add(const ros::MessageEvent<M const>& event) {
    if (event.getPublisherName() == ros::this_node::getName()) return;
    std::lock_guard<std::mutex> lock(mutex_);
    latest_ = event.getMessage();
  }
  ros::Subscriber sub_;
  std::mutex mutex_;
  typename M::ConstPtr latest_;
};

// The stamps of the disparity messages (1.4 MB each: only the stamp is kept). Its subscription
// also keeps the depth chain running (its inputs are subscribed only while someone listens).
class DisparityStamps {
 public:
  explicit DisparityStamps(ros::NodeHandle& nh) : sub_(nh.subscribe("disparity", 30, &DisparityStamps::add, this)) {}
  ~DisparityStamps() { sub_.shutdown(); }
  size_t count() {
    std::lock_guard<std::mutex> lock(mutex_);
    return count_;
  }
  bool waitForCount(size_t n, double timeout_s) {
    std::unique_lock<std::mutex> lock(mutex_);
    return cv_.wait_for(lock, std::chrono::duration<double>(timeout_s), [&] { return count_ >= n; });
  }

 private:
  void add(const stereo_msgs::DisparityImage::ConstPtr&) {
    {
      std::lock_guard<std::mutex> lock(mutex_);
      ++count_;
    }
    cv_.notify_all();
  }
  ros::Subscriber sub_;
  std::mutex mutex_;
  std::condition_variable cv_;
  size_t count_ = 0;
};

// The driver's camera_info messages whose principal point lies off the image beyond the margin
// the driver documents (a quarter of the image's size past each edge, docs/nodelets.md; a
// rectified pair's cx' may lie a little outside): none may. The first one is kept to say which.
class OffImageCount {
 public:
  OffImageCount(ros::NodeHandle& nh, const std::string& topic)
      : sub_(nh.subscribe(topic, 30, &OffImageCount::add, this)) {}
  ~OffImageCount() { sub_.shutdown(); }
  int count() const { return count_; }
  std::string first() const {
    std::lock_guard<std::mutex> lock(mutex_);
    return first_;
  }

 private:
  void add(const ros::MessageEvent<CameraInfo const>& event) {
    if (event.getPublisherName() == ros::this_node::getName()) return;
    const CameraInfo& c = *event.getMessage();
    const auto inside = [](double v, double size) { return v >= -0.25 * size && v <= 1.25 * size; };
    if (inside(c.K[2], c.width) && inside(c.K[5], c.height) && inside(c.P[2], c.width) && inside(c.P[6], c.height))
      return;
    if (count_++ == 0) {
      std::lock_guard<std::mutex> lock(mutex_);
      first_ = "K cx " + std::to_string(c.K[2]) + ", cy " + std::to_string(c.K[5]) + "; P cx' " + std::to_string(c.P[2]) +
               ", cy' " + std::to_string(c.P[6]) + " in " + std::to_string(c.width) + "x" + std::to_string(c.height);
    }
  }
  ros::Subscriber sub_;
  std::atomic<int> count_{0};
  mutable std::mutex mutex_;
  std::string first_;
};

struct Fixture {
  ros::NodeHandle nh;
  OffImageCount off_image_left{nh, "left/camera_info"}, off_image_right{nh, "right/camera_info"};
  Latest<Image> left_raw{nh, "left/image_raw"}, right_raw{nh, "right/image_raw"};
  Latest<CameraInfo> left_info{nh, "left/camera_info"}, right_info{nh, "right/camera_info"};
  Latest<CalibrationMode> mode{nh, "calibration_mode"};
  Latest<StereoPatternObservation> observations{nh, "calibration/observations"};
  Latest<StereoPatternObservation> windows{nh, "calibration/window_observations"};
  DisparityStamps disparity{nh};
  Collector<CalibrationStatus> status{nh, "calibration/status"};
  ros::Publisher pub_left_raw = nh.advertise<Image>("left/image_raw", 20);
  ros::Publisher pub_right_raw = nh.advertise<Image>("right/image_raw", 20);
  ros::Publisher pub_left_scene = nh.advertise<Image>("left/image_scene", 20);
  ros::Publisher pub_right_scene = nh.advertise<Image>("right/image_scene", 20);
  ros::Publisher pub_left_rect = nh.advertise<Image>("left/image_rect", 20);
  ros::Publisher pub_right_rect = nh.advertise<Image>("right/image_rect", 20);
  ros::Publisher pub_left_info = nh.advertise<CameraInfo>("left/camera_info", 20);
  ros::Publisher pub_right_info = nh.advertise<CameraInfo>("right/camera_info", 20);
  ros::Publisher pub_mode = nh.advertise<CalibrationMode>("calibration_mode", 20);
  ros::Publisher pub_observations = nh.advertise<StereoPatternObservation>("calibration/observations", 20);
  ros::Publisher pub_windows = nh.advertise<StereoPatternObservation>("calibration/window_observations", 20);
  ros::Publisher pub_coverage = nh.advertise<embedded_calibration_stereo::DisparityCoverage>("disparity_coverage", 20);
};

Fixture* fixture = nullptr;

// Random corruptions of each message type's fields.
class Corrupter {
 public:
  explicit Corrupter(unsigned seed) : rng_(seed) {}

  int uniform(int lo, int hi) { return std::uniform_int_distribution<int>(lo, hi)(rng_); }
  bool chance(double p) { return std::bernoulli_distribution(p)(rng_); }
  template <class T>
  const T& pick(const std::vector<T>& values) {
    return values[static_cast<size_t>(uniform(0, static_cast<int>(values.size()) - 1))];
  }
  uint32_t anyU32() { return std::uniform_int_distribution<uint32_t>()(rng_); }
  double oddDouble() {
    return pick<double>({std::numeric_limits<double>::quiet_NaN(), std::numeric_limits<double>::infinity(),
                         -std::numeric_limits<double>::infinity(), 0.0, -1.0, 1e30, -1e30, 1e-30,
                         std::uniform_real_distribution<double>(-1e4, 1e4)(rng_)});
  }
  float oddFloat() { return static_cast<float>(oddDouble()); }
  std::string oddText() {
    return pick<std::string>({"", "x", "stereo_left_optical_frame", "/", std::string(300, 'a'), "\xff\xfe"});
  }

  // A stamp relative to the driver's latest `now`.
  ros::Time stamp(const ros::Time& now) {
    switch (uniform(0, 9)) {
      case 0: return now + ros::Duration(20.0);
      case 1: return now - ros::Duration(5.0);
      case 2: return ros::Time(0, 0);
      case 3: return ros::Time(chance(0.5) ? std::numeric_limits<uint32_t>::max() : std::numeric_limits<int32_t>::max(), 0);
      case 4: return now + ros::Duration(std::uniform_real_distribution<double>(-0.5, 0.5)(rng_));
      case 5: return now;  // the stamp of a live frame
      case 6: return now + ros::Duration(std::uniform_real_distribution<double>(0.5, 1.9)(rng_));  // within tolerance
      default: return now + ros::Duration(uniform(1, 3) * kFramePeriodS);
    }
  }

  void corrupt(Image* m) {
    switch (uniform(0, 8)) {
      case 0: m->width = pick<uint32_t>({0, 1, m->width / 2, m->width * 2, 65535, 0xFFFFFFFFu}); break;
      case 1: m->height = pick<uint32_t>({0, 1, m->height / 2, m->height * 2, 65536, 0xFFFFFFFFu}); break;
      case 2: m->step = pick<uint32_t>({0, 1, m->step - 1, m->step * 2, 65536, 0xFFFFFFFFu}); break;
      case 3:
        m->encoding = pick<std::string>({"", "mono16", "bgr8", "rgb8", "rgba8", "32FC1", "16UC1", "8UC3", "yuv422",
                                         "bayer_rggb8", "garbage"});
        break;
      case 4: m->data.resize(pick<size_t>({0, 1, m->data.size() / 2, m->data.size() + 1000})); break;
      case 5:
        for (auto& byte : m->data) byte = static_cast<uint8_t>(rng_());
        break;
      case 6: m->is_bigendian = static_cast<uint8_t>(uniform(0, 255)); break;
      case 7: m->header.frame_id = oddText(); break;
      default: m->header.seq = anyU32(); break;
    }
  }

  void corrupt(CameraInfo* m) {
    switch (uniform(0, 11)) {
      case 10: {  // a principal point off the image, K's and P's alike (no pair check sees it)
        const double shift = pick<double>({5000.0, -5000.0, 100000.0, 400.0});
        const size_t k = chance(0.5) ? 2 : 5;
        m->K[k] += shift;
        m->P[k == 2 ? 2 : 6] += shift;
        break;
      }
      case 11: m->P[2] += pick<double>({4.0, -30.0, 5000.0}); break;  // cx' alone
      case 0: m->K[static_cast<size_t>(uniform(0, 8))] = oddDouble(); break;
      case 1: m->P[static_cast<size_t>(uniform(0, 11))] = oddDouble(); break;
      case 2: m->R[static_cast<size_t>(uniform(0, 8))] = oddDouble(); break;
      case 3:
        m->D.resize(pick<size_t>({0, 1, 3, 4, 5, 8, 12, 14, 100}));
        for (double& d : m->D)
          if (chance(0.5)) d = oddDouble();
        break;
      case 4: m->distortion_model = pick<std::string>({"", "equidistant", "rational_polynomial", "garbage"}); break;
      case 5: m->width = pick<uint32_t>({0, 1, m->width / 2, 65535, 0xFFFFFFFFu}); break;
      case 6: m->height = pick<uint32_t>({0, 1, m->height / 2, 65535, 0xFFFFFFFFu}); break;
      case 7:
        m->binning_x = pick<uint32_t>({0, 2, 1000, 0xFFFFFFFFu});
        m->binning_y = pick<uint32_t>({0, 3, 0xFFFFFFFFu});
        break;
      case 8:
        m->roi.x_offset = anyU32() % 2000;
        m->roi.y_offset = anyU32() % 2000;
        m->roi.width = anyU32() % 2000;
        m->roi.height = anyU32() % 2000;
        m->roi.do_rectify = chance(0.5);
        break;
      default: m->header.frame_id = oddText(); break;
    }
  }

  void corrupt(CalibrationMode* m) {
    switch (uniform(0, 2)) {
      case 0: m->light_on = chance(0.5); break;
      case 1: m->settled = chance(0.5); break;
      default: m->calibration_epoch = chance(0.5) ? anyU32() : m->calibration_epoch + 1; break;
    }
  }

  void corrupt(StereoPatternObservation* m) {
    if (chance(0.15)) {  // the scene correspondences of a window observation
      if (m->scene.empty() || chance(0.3)) m->scene.resize(pick<size_t>({0, 1, 5000}));
      for (auto& match : m->scene)
        if (chance(0.2)) (chance(0.5) ? match.left_u : match.right_v) = oddFloat();
      return;
    }
    auto& side = chance(0.5) ? m->left : m->right;
    if (side.empty() || chance(0.1)) {
      side.resize(pick<size_t>({0, 1, 6, 200}));
      for (BoardObservation& b : side) b.board_id = static_cast<uint16_t>(uniform(0, 65535));
      return;
    }
    BoardObservation& b = side[static_cast<size_t>(uniform(0, static_cast<int>(side.size()) - 1))];
    switch (uniform(0, 6)) {
      case 0: b.board_id = static_cast<uint16_t>(pick<int>({0, 5, 6, 7, 100, 65535})); break;
      case 1:
        if (!b.corner_ids.empty()) b.corner_ids[static_cast<size_t>(uniform(0, static_cast<int>(b.corner_ids.size()) - 1))] =
            static_cast<uint16_t>(uniform(0, 65535));
        break;
      case 2:
        if (b.corner_ids.size() > 1) b.corner_ids[1] = b.corner_ids[0];  // a duplicate id
        break;
      case 3:
        for (float& u : b.u)
          if (chance(0.3)) u = oddFloat();
        break;
      case 4:
        for (float& v : b.v)
          if (chance(0.3)) v = oddFloat();
        break;
      case 5: b.u.resize(b.u.size() / 2); break;
      default:
        b.corner_ids.resize(pick<size_t>({0, 1, 5000}));
        b.u.resize(b.corner_ids.size(), 100.0f);
        b.v.resize(b.corner_ids.size(), 100.0f);
        break;
    }
  }

  // A stamp 0.5-1.9 s after the driver's latest `now`: within the stamp tolerance (2 s).
  ros::Time aheadWithinTolerance(const ros::Time& now) {
    return now + ros::Duration(std::uniform_real_distribution<double>(0.5, 1.9)(rng_));
  }

  // A copy of `base` under `stamp`, with 1-3 corruptions with probability `p`.
  template <class M>
  boost::shared_ptr<M> variant(const M& base, const ros::Time& stamp, double p) {
    auto m = boost::make_shared<M>(base);
    m->header.stamp = stamp;
    if (chance(p))
      for (int i = uniform(1, 3); i > 0; --i) corrupt(m.get());
    return m;
  }

 private:
  std::mt19937 rng_;
};

// set_camera_info calls changing the calibration in force: a principal point far off the image
// on both cameras alike (a consistent pair), or on one camera: cx' alone (half a pair), focal
// lengths 1.3x the device's, or random corruptions. Returns the calls the driver put in force
// at once (not staged).
int callSetCameraInfo(Corrupter& fuzz, const CameraInfo& left_info, const CameraInfo& right_info) {
  const int kind = fuzz.uniform(0, 3);
  std::vector<std::pair<std::string, CameraInfo>> calls;
  if (kind == 0) {
    for (const bool left : {true, false}) {
      CameraInfo c = left ? left_info : right_info;
      c.K[5] += 100000;
      c.P[6] += 100000;
      calls.emplace_back(left ? "left/set_camera_info" : "right/set_camera_info", c);
    }
  } else {
    const bool left = fuzz.chance(0.5);
    CameraInfo c = left ? left_info : right_info;
    if (kind == 1) {
      c.P[2] += 4;
    } else if (kind == 2) {
      for (const size_t k : {0, 4}) c.K[k] *= 1.3;
      for (const size_t k : {0, 3, 5}) c.P[k] *= 1.3;
    } else {
      for (int i = fuzz.uniform(1, 3); i > 0; --i) fuzz.corrupt(&c);
    }
    calls.emplace_back(left ? "left/set_camera_info" : "right/set_camera_info", c);
  }
  int in_force = 0;
  for (const auto& [service, info] : calls) {
    sensor_msgs::SetCameraInfo srv;
    srv.request.camera_info = info;
    if (ros::service::call(service, srv) && srv.response.success && srv.response.status_message.rfind("staged:", 0) != 0)
      ++in_force;
  }
  return in_force;
}

// The inputs of a user or another node (rounds of group 10-13): a burst of calibration_mode
// stamped ahead within the tolerance, a set_camera_info, a window observation (a copy or
// corrupted), a disparity_coverage with odd values. Returns the messages sent.
int outsideRound(Corrupter& fuzz, Fixture& f, int group, const ros::Time& stamp, const CalibrationMode& mode,
                 const CameraInfo& left_info, const CameraInfo& right_info, const StereoPatternObservation& observations,
                 int* accepted) {
  if (group == 10) {
    for (int i = 0; i < 5; ++i) {
      CalibrationMode m = mode;
      m.header.stamp = fuzz.aheadWithinTolerance(mode.header.stamp);
      m.light_on = fuzz.chance(0.5);
      m.settled = fuzz.chance(0.5);
      f.pub_mode.publish(m);
    }
    return 5;
  }
  if (group == 11) {
    *accepted += callSetCameraInfo(fuzz, left_info, right_info);
    return 1;
  }
  if (group == 12) {
    const auto window = f.windows.get();
    f.pub_windows.publish(fuzz.variant(window ? *window : observations, stamp, 0.7));
    return 1;
  }
  embedded_calibration_stereo::DisparityCoverage coverage;
  coverage.header.stamp = stamp;
  coverage.valid_fraction = static_cast<float>(
      fuzz.pick<double>({std::numeric_limits<double>::quiet_NaN(), -1.0, 2.0, 0.0, 0.5, 1e30}));
  f.pub_coverage.publish(coverage);
  return 1;
}

bool sameValue(double a, double b) { return std::abs(a - b) <= 1e-6 * std::max(1.0, std::abs(b)); }

}  // namespace

// The calibration files in `dir`: both parse and form one stereo pair, the one the driver
// publishes.
void expectFilesArePublishedPair(Fixture& f, const std::string& dir) {
  std::string left_name, right_name;
  CameraInfo left, right;
  ASSERT_TRUE(camera_calibration_parsers::readCalibration(dir + "/left.yaml", left_name, left));
  ASSERT_TRUE(camera_calibration_parsers::readCalibration(dir + "/right.yaml", right_name, right));
  EXPECT_EQ(left.width, right.width);
  EXPECT_EQ(left.height, right.height);
  EXPECT_TRUE(sameValue(left.P[0], right.P[0])) << "fx' " << left.P[0] << " vs " << right.P[0];
  EXPECT_TRUE(sameValue(left.P[5], right.P[5])) << "fy' " << left.P[5] << " vs " << right.P[5];
  EXPECT_TRUE(sameValue(left.P[6], right.P[6])) << "cy' " << left.P[6] << " vs " << right.P[6];
  EXPECT_EQ(left.P[3], 0.0);
  EXPECT_LT(right.P[3], 0.0) << "right Tx = -fx' * baseline";
  for (const CameraInfo* info : {&left, &right})
    for (double v : info->K) EXPECT_TRUE(std::isfinite(v));
  // What the driver publishes now (this node published nothing since).
  ASSERT_TRUE(f.disparity.waitForCount(f.disparity.count() + 2, 5.0));
  const auto published_left = f.left_info.get(), published_right = f.right_info.get();
  for (size_t i = 0; i < 12; ++i) {
    EXPECT_TRUE(sameValue(published_left->P[i], left.P[i])) << "left P[" << i << "]";
    EXPECT_TRUE(sameValue(published_right->P[i], right.P[i])) << "right P[" << i << "]";
  }
}

TEST(GraphFuzz, Setup) {
  ASSERT_TRUE(ros::service::waitForService("calibration/recalibrate", 30000));
  ASSERT_TRUE(fixture->disparity.waitForCount(10, 40.0)) << "no disparity";
  // A commit, so that calibration files exist before the fuzzing (a 3 % zoom to correct).
  embedded_calibration_stereo::SetRigDrift drift;
  drift.request.focal_scale = 1.03;
  ASSERT_TRUE(ros::service::call("sim/set_drift", drift));
  ASSERT_TRUE(drift.response.success) << drift.response.message;
  ASSERT_TRUE(fixture->status.waitFor(
      [](const auto& m) { return std::any_of(m.begin(), m.end(), [](const auto& s) { return s->accepted; }); }, 40.0))
      << "no calibration committed";
  // The tracker tracks whole bursts: its per-frame observations may not come before its first
  // window observation does.
  ASSERT_TRUE(test_support::waitUntil([] { return fixture->observations.get() || fixture->windows.get(); }, 30.0))
      << "no observations from the tracker";
}

TEST(GraphFuzz, CorruptedInputsOnEveryTopicLeaveTheHeadRunningAndItsCalibrationConsistent) {
  const int manager = test_support::nodePid("/stereo/stereo_manager");
  ASSERT_GT(manager, 0) << "cannot find the manager's pid";
  int seed = static_cast<int>(kSeed);  // ~seed: another sequence, to explore (the suite uses kSeed)
  ros::param::get("~seed", seed);
  Corrupter fuzz(static_cast<unsigned>(seed));
  Fixture& f = *fixture;
  const ros::WallTime start = ros::WallTime::now();
  int rounds = 0, messages = 0, accepted = 0;
  for (; rounds < kRounds && (ros::WallTime::now() - start).toSec() < kFuzzSeconds; ++rounds) {
    const auto left_raw = f.left_raw.get(), right_raw = f.right_raw.get();
    const auto left_info = f.left_info.get(), right_info = f.right_info.get();
    const auto mode = f.mode.get();
    const auto observations = f.observations.get() ? f.observations.get() : f.windows.get();
    ASSERT_TRUE(left_raw && right_raw && left_info && right_info && mode && observations);
    const ros::Time stamp = fuzz.stamp(mode->header.stamp);
    const int group = fuzz.uniform(0, 13);
    if (group <= 1) {  // tracker and separator: images + mode
      f.pub_left_raw.publish(fuzz.variant(*left_raw, stamp, 0.5));
      f.pub_right_raw.publish(fuzz.variant(*right_raw, stamp, 0.5));
      f.pub_mode.publish(fuzz.variant(*mode, stamp, 0.5));
      messages += 3;
    } else if (group <= 3) {  // rectifier or disparity: images + camera_info
      const bool rect = fuzz.chance(0.5);
      (rect ? f.pub_left_rect : f.pub_left_scene).publish(fuzz.variant(*left_raw, stamp, 0.5));
      (rect ? f.pub_right_rect : f.pub_right_scene).publish(fuzz.variant(*right_raw, stamp, 0.5));
      f.pub_left_info.publish(fuzz.variant(*left_info, stamp, 0.5));
      f.pub_right_info.publish(fuzz.variant(*right_info, stamp, 0.5));
      messages += 4;
    } else if (group <= 5) {  // calibrator: a settled light-on mode + observations
      CalibrationMode on = *mode;
      on.light_on = on.settled = true;
      f.pub_mode.publish(fuzz.variant(on, stamp, 0.2));
      f.pub_observations.publish(fuzz.variant(*observations, stamp, 0.8));
      messages += 2;
    } else if (group >= 10) {  // a user's or another node's inputs
      messages += outsideRound(fuzz, f, group, stamp, *mode, *left_info, *right_info, *observations, &accepted);
    } else {  // one message on one topic
      switch (fuzz.uniform(0, 9)) {
        case 0: f.pub_left_raw.publish(fuzz.variant(*left_raw, stamp, 1.0)); break;
        case 1: f.pub_right_raw.publish(fuzz.variant(*right_raw, stamp, 1.0)); break;
        case 2: f.pub_left_scene.publish(fuzz.variant(*left_raw, stamp, 1.0)); break;
        case 3: f.pub_right_rect.publish(fuzz.variant(*right_raw, stamp, 1.0)); break;
        case 4: f.pub_left_info.publish(fuzz.variant(*left_info, stamp, 1.0)); break;
        case 5: f.pub_right_info.publish(fuzz.variant(*right_info, stamp, 1.0)); break;
        case 6: f.pub_mode.publish(fuzz.variant(*mode, stamp, 1.0)); break;
        default: f.pub_observations.publish(fuzz.variant(*observations, stamp, 1.0)); break;
      }
      ++messages;
    }
    ros::WallDuration(kRoundPeriodS).sleep();  // pacing the publisher, not synchronisation
  }
  std::printf("fuzz: %d rounds, %d messages in %.1f s (seed %u); %d set_camera_info calls put in force at once\n",
              rounds, messages, (ros::WallTime::now() - start).toSec(), static_cast<unsigned>(seed), accepted);
  ASSERT_TRUE(test_support::processRuns(manager)) << "the nodelet manager died";

  // The manager answers (its XML-RPC), disparity flows.
  EXPECT_EQ(test_support::nodePid("/stereo/stereo_manager"), manager) << "the manager does not answer";
  const size_t disparity_before = f.disparity.count();
  EXPECT_TRUE(f.disparity.waitForCount(disparity_before + 15, 10.0)) << "disparity does not flow after the fuzzing";
  // The calibrator answers a request.
  Recalibrate recalibrate;
  recalibrate.request.frames = 5;
  recalibrate.request.timeout_s = 5.0;
  recalibrate.request.dry_run = true;
  const ros::WallTime asked = ros::WallTime::now();
  ASSERT_TRUE(ros::service::call("calibration/recalibrate", recalibrate)) << "the calibrator does not answer";
  std::printf("recalibrate (dry run) after the fuzzing: %s in %.1f s: %s\n",
              recalibrate.response.success ? "success" : "false", (ros::WallTime::now() - asked).toSec(),
              recalibrate.response.message.c_str());
  EXPECT_TRUE(test_support::processRuns(manager)) << "the nodelet manager died";
  EXPECT_EQ(f.off_image_left.count() + f.off_image_right.count(), 0)
      << "the driver published a calibration with a principal point off the image: left " << f.off_image_left.first()
      << "; right " << f.off_image_right.first();

  std::string dir;
  ASSERT_TRUE(ros::param::get("~calibration_dir", dir));
  expectFilesArePublishedPair(f, dir);
}

int main(int argc, char** argv) {
  return test_support::runTestsWithFixture(argc, argv, "graph_fuzz_test", 3, &fixture);
}
