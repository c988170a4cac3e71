// rostest: zero-copy through the depth chain (zero_copy.test). The simulated driver, the
// Separator, the Rectifier and the Disparity are loaded into THIS process (one nodelet::Loader:
// the same "manager"), and the test's subscribers are probes in that same process.
//
// What each check proves (and why it could fail):
//  - depth mode, image_scene is the image_raw object (pointer equality by stamp): had the
//    Separator published a copy, or had either hop been serialised, the addresses would differ;
//  - every inbound connection of left|right/image_rect and camera_info is INTRAPROCESS in roscpp's
//    bus info: roscpp keeps ONE Subscription per topic and process, shared by the Disparity and
//    the probes, so these are the very links the Disparity receives through; INTRAPROCESS means
//    roscpp hands over the published shared pointer, TCPROS would mean serialise + deserialise
//    (the control test shows a TCPROS link is reported as such, through a relay in another
//    process);
//  - two independent probe subscriptions receive the same image_rect object: the Subscription
//    gives one object to all its const callbacks (the Disparity's included). Alone this does
//    not prove the absence of serialisation (roscpp also shares one deserialised object among
//    callbacks), hence the bus-info check above;
//  - the Disparity's "input copies" diagnostic stays 0 while it publishes disparity for those
//    stamps: its cv::Mat views point into the received messages' buffers (no cv_bridge
//    conversion). The control test feeds bgr8 images to another Disparity and sees the count
//    rise, so the counter is not a constant 0.
#include <diagnostic_msgs/DiagnosticArray.h>
#include <gtest/gtest.h>
#include <nodelet/loader.h>
#include <ros/network.h>
#include <ros/xmlrpc_manager.h>
#include <xmlrpcpp/XmlRpcClient.h>
#include <sensor_msgs/CameraInfo.h>
#include <stereo_msgs/DisparityImage.h>

#include <set>

#include "depth_test_utils.h"
#include "driver_test_utils.h"

namespace test_support = embedded_calibration_stereo::test_support;

using diagnostic_msgs::DiagnosticArray;
using test_support::Collector;
using sensor_msgs::CameraInfo;
using sensor_msgs::Image;
using stereo_msgs::DisparityImage;

namespace {

std::unique_ptr<nodelet::Loader> loader;  // created in main, after ros::init
test_support::TempDir calibration_dir("ecs_zero_copy");

void setParams(const std::string& name, const std::map<std::string, XmlRpc::XmlRpcValue>& params) {
  for (const auto& p : params) ros::param::set(name + "/" + p.first, p.second);
}

// Driver (sim, light off: depth mode), Separator, Rectifier and Disparity in namespace /zc.
bool loadDepthChain() {
  static bool loaded = false;
  if (loaded) return true;
  setParams("/zc/camera_driver", {{"backend", "sim"},
                                  {"sim_config", std::string(ECS_SOURCE_DIR) + "/config/sim_rig.yaml"},
                                  {"fps", 10.0},
                                  {"calibration_period_s", 0.0},
                                  {"left_camera_info_url", "file://" + calibration_dir.path + "/left.yaml"},
                                  {"right_camera_info_url", "file://" + calibration_dir.path + "/right.yaml"}});
  const ros::M_string none;
  const std::vector<std::string> no_args;
  loaded = loader->load("/zc/camera_driver", "embedded_calibration_stereo/CameraDriver", none, no_args) &&
           loader->load("/zc/separator", "embedded_calibration_stereo/Separator", none, no_args) &&
           loader->load("zc/rectifier", "embedded_calibration_stereo/Rectifier", none, no_args) &&
           loader->load("zc/disparity", "embedded_calibration_stereo/Disparity", none, no_args);
  return loaded;
}

// This process's bus info (its own XML-RPC getBusInfo, as rosnode info reads it): per inbound
// connection of `topic`, its transport.
std::vector<std::string> inboundTransports(const std::string& topic) {
  std::string host;
  uint32_t port = 0;
  if (!ros::network::splitURI(ros::XMLRPCManager::instance()->getServerURI(), host, port)) return {};
  XmlRpc::XmlRpcClient client(host.c_str(), static_cast<int>(port), "/");
  XmlRpc::XmlRpcValue request, response;
  request[0] = ros::this_node::getName();
  if (!client.execute("getBusInfo", request, response) || int(response[0]) != 1) return {};
  XmlRpc::XmlRpcValue& info = response[2];
  std::vector<std::string> transports;
  for (int i = 0; i < info.size(); ++i) {
    // [connection id, peer, direction "i"/"o"/"b", transport, topic, connected, info]
    XmlRpc::XmlRpcValue& c = info[i];
    if (std::string(c[2]) == "i" && std::string(c[4]) == topic) transports.push_back(std::string(c[3]));
  }
  return transports;
}

// The value of `key` in the status of /diagnostics of `node` (diagnostic_updater names it
// "<node name without the leading slash>: <task>"), or "".
std::string diagnosticValue(const DiagnosticArray& array, const std::string& node, const std::string& key) {
  for (const auto& status : array.status) {
    if (status.name.rfind(node + ":", 0) != 0) continue;
    for (const auto& kv : status.values)
      if (kv.key == key) return kv.value;
  }
  return "";
}

}  // namespace

// Light off: image_scene is the very object the driver published on image_raw.
TEST(ZeroCopy, SeparatorRepublishesTheDriverObjects) {
  ros::NodeHandle nh("/zc");
  Collector<Image> raw(nh, "left/image_raw", 100), scene(nh, "left/image_scene", 100);
  ASSERT_TRUE(loadDepthChain());
  ASSERT_TRUE(scene.waitFor(
      [&](const std::vector<Image::ConstPtr>& m) {
        int matched = 0;
        for (const auto& s : m) matched += test_support::findByStamp(raw.snapshot(), s->header.stamp) != nullptr;
        return matched >= 5;
      },
      30.0));
  int identical = 0;
  for (const auto& s : scene.snapshot()) {
    const auto r = test_support::findByStamp(raw.snapshot(), s->header.stamp);
    if (!r) continue;
    EXPECT_EQ(s.get(), r.get()) << "image_scene at " << s->header.stamp << " is not the image_raw object";
    identical += s.get() == r.get();
  }
  std::printf("depth mode: %d image_scene messages are the driver's image_raw objects\n", identical);
  EXPECT_GE(identical, 5);
}

// The Disparity's inputs arrive by pointer from the Rectifier, are shared (not copied) by the
// Disparity, and disparity is produced for those frames.
TEST(ZeroCopy, DisparityReceivesTheRectifierObjectsWithoutCopies) {
  ros::NodeHandle nh("/zc");
  Collector<Image> rect_a(nh, "left/image_rect", 100), rect_b(nh, "left/image_rect", 100);
  Collector<DisparityImage> disparity(nh, "disparity", 50);
  Collector<DiagnosticArray> diagnostics(nh, "/diagnostics", 500);
  ASSERT_TRUE(loadDepthChain());
  ASSERT_TRUE(disparity.waitForCount(5, 30.0)) << "no disparity from the in-process chain";

  for (const char* side : {"left", "right"}) {
    for (const std::string& topic : {std::string("/zc/") + side + "/image_rect", std::string("/zc/") + side + "/camera_info"}) {
      const auto transports = inboundTransports(topic);
      ASSERT_FALSE(transports.empty()) << topic << ": no inbound connection in this process";
      for (const auto& t : transports) EXPECT_EQ(t, "INTRAPROCESS") << topic;
      std::printf("%s: %zu inbound connection(s), %s\n", topic.c_str(), transports.size(), transports[0].c_str());
    }
  }

  // Both probes got the same objects (and so did the Disparity, a third callback of the same
  // Subscription), for the stamps disparity was computed for.
  const auto a = rect_a.snapshot(), b = rect_b.snapshot();
  int identical = 0, with_disparity = 0;
  for (const auto& m : a) {
    const auto other = test_support::findByStamp(b, m->header.stamp);
    if (!other) continue;
    EXPECT_EQ(m.get(), other.get()) << "two subscriptions got different image_rect objects";
    EXPECT_EQ(m->data.data(), other->data.data());
    identical += m.get() == other.get();
    with_disparity += test_support::findByStamp(disparity.snapshot(), m->header.stamp) != nullptr;
  }
  EXPECT_GE(identical, 5);
  EXPECT_GE(with_disparity, 3) << "image_rect frames probed have no disparity of the same stamp";

  // The Disparity's own count of inputs cv_bridge had to copy, in a report issued after
  // disparity frames were published.
  std::string copies, outputs;
  ASSERT_TRUE(diagnostics.waitFor(
      [&](const std::vector<DiagnosticArray::ConstPtr>& m) {
        for (auto it = m.rbegin(); it != m.rend(); ++it) {
          outputs = diagnosticValue(**it, "zc/disparity", "output frames");
          if (!outputs.empty() && std::stoul(outputs) >= 5) {
            copies = diagnosticValue(**it, "zc/disparity", "input copies");
            return true;
          }
        }
        return false;
      },
      10.0))
      << "no diagnostics of /zc/disparity with output frames";
  std::printf("%d image_rect objects shared by both probes, %d with disparity; /zc/disparity: %s output "
              "frames, input copies %s\n",
              identical, with_disparity, outputs.c_str(), copies.c_str());
  EXPECT_EQ(copies, "0");
  std::string rect_copies;
  for (const auto& array : diagnostics.snapshot()) {
    const std::string v = diagnosticValue(*array, "zc/rectifier", "input copies");
    if (!v.empty()) rect_copies = v;  // the latest report wins
  }
  EXPECT_EQ(rect_copies, "0") << "the Rectifier copied its inputs (or reported nothing)";
}

// Controls: the checks above can fail. A link from another process (topic_tools relay, started
// by zero_copy.test) is reported TCPROS, and a Disparity fed bgr8 images (converted to mono8 by
// cv_bridge: a copy) counts its input copies.
TEST(ZeroCopyControls, ChecksDetectSerialisationAndCopies) {
  ros::NodeHandle nh("/zc");
  Collector<Image> relayed(nh, "relayed/left/image_rect", 10);
  ASSERT_TRUE(loadDepthChain());
  ASSERT_TRUE(relayed.waitForCount(1, 20.0)) << "the relay in another process delivers nothing";
  const auto transports = inboundTransports("/zc/relayed/left/image_rect");
  ASSERT_FALSE(transports.empty());
  EXPECT_EQ(transports[0], "TCPROS") << "a link from another process is not reported as serialised";

  ros::NodeHandle copy_nh("/copy");
  Collector<DisparityImage> disparity(copy_nh, "disparity", 10);
  Collector<DiagnosticArray> diagnostics(copy_nh, "/diagnostics", 500);
  ros::Publisher image_pubs[2] = {copy_nh.advertise<Image>("left/image_rect", 5),
                                  copy_nh.advertise<Image>("right/image_rect", 5)};
  ros::Publisher info_pubs[2] = {copy_nh.advertise<CameraInfo>("left/camera_info", 5),
                                 copy_nh.advertise<CameraInfo>("right/camera_info", 5)};
  ASSERT_TRUE(loader->load("copy/disparity", "embedded_calibration_stereo/Disparity", ros::M_string(), {}));
  const ros::WallTime deadline = ros::WallTime::now() + ros::WallDuration(10.0);
  while (!image_pubs[0].getNumSubscribers() || !image_pubs[1].getNumSubscribers() ||
         !info_pubs[0].getNumSubscribers() || !info_pubs[1].getNumSubscribers()) {
    ASSERT_LT(ros::WallTime::now(), deadline) << "the control Disparity did not subscribe";
    ros::WallDuration(0.01).sleep();  // no event to wait on for a connection
  }
  for (uint32_t sec = 1; sec <= 3; ++sec) {
    for (int side = 0; side < 2; ++side) {
      auto image = boost::make_shared<Image>();
      image->header.stamp = ros::Time(sec, 0);
      image->header.frame_id = "cam";
      image->encoding = "bgr8";
      image->width = 160;
      image->height = 120;
      image->step = image->width * 3;
      image->data.resize(size_t(image->step) * image->height);
      for (size_t i = 0; i < image->data.size(); ++i) image->data[i] = uint8_t((i * 7919) % 251);
      auto info = boost::make_shared<CameraInfo>();
      info->header = image->header;
      info->width = image->width;
      info->height = image->height;
      info->K = {100, 0, 80, 0, 100, 60, 0, 0, 1};
      info->R = {1, 0, 0, 0, 1, 0, 0, 0, 1};
      info->P = {100, 0, 80, side == 0 ? 0.0 : -10.0, 0, 100, 60, 0, 0, 0, 1, 0};
      info->distortion_model = "plumb_bob";
      info->D = {0, 0, 0, 0, 0};
      image_pubs[side].publish(image);
      info_pubs[side].publish(info);
    }
  }
  ASSERT_TRUE(disparity.waitForCount(1, 10.0)) << "the control Disparity published nothing from bgr8 inputs";
  std::string copies;
  EXPECT_TRUE(diagnostics.waitFor(
      [&](const std::vector<DiagnosticArray::ConstPtr>& m) {
        for (const auto& a : m) {
          copies = diagnosticValue(*a, "copy/disparity", "input copies");
          if (!copies.empty() && std::stoul(copies) > 0) return true;
        }
        return false;
      },
      10.0))
      << "bgr8 inputs converted by cv_bridge were not counted as copies (last value '" << copies << "')";
  std::printf("control: relayed link %s; bgr8 Disparity input copies %s\n", transports[0].c_str(), copies.c_str());
  loader->unload("/copy/disparity");
}

int main(int argc, char** argv) {
  testing::InitGoogleTest(&argc, argv);
  ros::init(argc, argv, "zero_copy_test");
  ros::AsyncSpinner spinner(2);
  spinner.start();
  loader = std::make_unique<nodelet::Loader>(false);
  const int result = RUN_ALL_TESTS();
  loader.reset();  // unload the nodelets while ROS is still up
  return result;
}
