// StampGuard (which stamps a node's synchronised inputs let through), malformedImage, and the
// bounded service call helpers that need no master (probeUri against sockets of this test).
// The scenarios are written out by hand with a simulated clock: the expected outcome of each
// message follows from the stamps, not from the guard's code.
#include <arpa/inet.h>
#include <gtest/gtest.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <unistd.h>

#include <string>
#include <vector>

#include "embedded_calibration_stereo/ros/caller_probe.h"
#include "embedded_calibration_stereo/ros/stamp_guard.h"

namespace ecsr = embedded_calibration_stereo;

namespace {

// Three inputs as the tracker's: left image, right image, calibration_mode; tolerance 2 s.
struct Harness {
  double now = 100.0;
  std::vector<std::string> warnings;
  ecsr::StampGuard guard{{"/left", "/right", "/mode"}, 2.0, "owner",
                         [this](const std::string& w) { warnings.push_back(w); }, [this] { return now; }};
  // One frame of all three inputs at `t` s; the number admitted.
  int frame(double t) {
    return guard.admit(0, ros::Time(t)) + guard.admit(1, ros::Time(t)) + guard.admit(2, ros::Time(t));
  }
};

bool contains(const std::string& text, const std::string& part) { return text.find(part) != std::string::npos; }

}  // namespace

TEST(StampGuard, LetsFramesThroughAndDropsFarFutureAndPastMessagesWithAWarningNamingTheTopic) {
  Harness h;
  for (int i = 0; i < 10; ++i) {
    EXPECT_EQ(h.frame(1000.0 + i / 30.0), 3);
    h.now += 1 / 30.0;
  }
  EXPECT_TRUE(h.warnings.empty());
  // 50 mode messages 20 s ahead, then 50 five seconds behind, between live frames.
  for (int i = 0; i < 50; ++i) {
    EXPECT_FALSE(h.guard.admit(2, ros::Time(1020.0 + i * 0.01)));
    EXPECT_FALSE(h.guard.admit(2, ros::Time(995.0 + i * 0.01)));
    if (i % 10 == 0) {
      EXPECT_EQ(h.frame(1000.4 + i / 300.0), 3) << "a live frame was dropped";
    }
    h.now += 0.01;
  }
  EXPECT_EQ(h.guard.dropped(), 100u);
  ASSERT_EQ(h.warnings.size(), 1u) << "throttled: one warning within 5 s";
  EXPECT_TRUE(contains(h.warnings[0], "/mode")) << h.warnings[0];
  EXPECT_TRUE(contains(h.warnings[0], "ahead of")) << h.warnings[0];
  EXPECT_TRUE(contains(h.warnings[0], "stamp_tolerance_s")) << h.warnings[0];
  EXPECT_TRUE(contains(h.warnings[0], "owner")) << h.warnings[0];
  // After the throttle period (live frames meanwhile) the next drop is reported with the count
  // since the last report.
  for (int i = 0; i < 150; ++i) {
    h.now += 1 / 30.0;
    EXPECT_EQ(h.frame(1000.6 + i / 30.0), 3);
  }
  EXPECT_FALSE(h.guard.admit(2, ros::Time(990.0)));
  ASSERT_EQ(h.warnings.size(), 2u);
  EXPECT_TRUE(contains(h.warnings[1], "dropped 100 messages")) << h.warnings[1];
  EXPECT_TRUE(contains(h.warnings[1], "behind")) << h.warnings[1];
}

TEST(StampGuard, MessagesWithinTheToleranceAndAfterAPauseAsLongAsTheirStepPass) {
  Harness h;
  EXPECT_EQ(h.frame(1000.0), 3);
  // A camera_info a frame ahead of its image, a late right image: within 2 s.
  EXPECT_TRUE(h.guard.admit(2, ros::Time(1001.9)));
  EXPECT_TRUE(h.guard.admit(1, ros::Time(998.1)));
  EXPECT_FALSE(h.guard.admit(0, ros::Time(1004.5)));  // beyond 2 s ahead of both others, no time passed
  h.now += 0.1;
  EXPECT_EQ(h.frame(1000.1), 3);
  // The source paused 10 s: its stamps advanced with the clock (let through as such, not as a
  // time jump followed after the tolerance).
  h.now += 10.0;
  EXPECT_EQ(h.frame(1010.1), 3);
  for (const auto& w : h.warnings) EXPECT_FALSE(contains(w, "following them")) << w;
}

TEST(StampGuard, FollowsATimeJumpOfEveryInputAfterTheToleranceButNeverAStrayStream) {
  Harness h;
  double t = 1000.0;
  for (int i = 0; i < 30; ++i, t += 0.1, h.now += 0.1) EXPECT_EQ(h.frame(t), 3);
  // A stray stream 5 s behind on the mode input, for 4 s, beside live frames: never followed.
  for (int i = 0; i < 40; ++i, t += 0.1, h.now += 0.1) {
    EXPECT_FALSE(h.guard.admit(2, ros::Time(t - 5.0)));
    EXPECT_EQ(h.frame(t), 3);
  }
  // The source restarts 100 s earlier (a bag replayed again): dropped until every message of an
  // input has been refused for 2 s, then followed.
  t -= 100.0;
  int admitted = 0, frames = 0;
  double first_admitted_at = -1;
  for (; frames < 40; ++frames, t += 0.1, h.now += 0.1) {
    const int n = h.frame(t);
    admitted += n;
    if (n > 0 && first_admitted_at < 0) first_admitted_at = frames * 0.1;
  }
  EXPECT_GE(first_admitted_at, 2.0 - 1e-9);
  EXPECT_LE(first_admitted_at, 2.0 + 0.1 + 1e-9);
  EXPECT_EQ(h.frame(t), 3) << "after the jump every input follows";
  bool said = false;
  for (const auto& w : h.warnings) said = said || contains(w, "following them");
  EXPECT_TRUE(said);
}

TEST(StampGuard, ResetForgetsTheStamps) {
  Harness h;
  EXPECT_EQ(h.frame(1000.0), 3);
  h.guard.reset();
  EXPECT_EQ(h.frame(5000.0), 3);
}

TEST(MalformedImage, RefusesDataShorterThanItsRowsAndShortStepsIncludingOverflowingSizes) {
  sensor_msgs::Image image;
  image.encoding = "mono8";
  image.width = 4;
  image.height = 3;
  image.step = 4;
  image.data.resize(12);
  EXPECT_EQ(ecsr::malformedImage(image), "");
  image.data.resize(11);
  EXPECT_NE(ecsr::malformedImage(image), "");
  image.data.resize(12);
  image.encoding = "bgr8";  // a row of 4 bgr8 pixels needs 12 bytes
  EXPECT_NE(ecsr::malformedImage(image), "");
  image.step = 12;
  image.data.resize(36);
  EXPECT_EQ(ecsr::malformedImage(image), "");
  // height x step wraps to 0 in 32 bits: an empty data array must not pass.
  image.encoding = "mono8";
  image.width = 1;
  image.height = 65536;
  image.step = 65536;
  image.data.clear();
  EXPECT_NE(ecsr::malformedImage(image), "");
  // An unknown encoding: only the data size is checked.
  image.encoding = "no-such-encoding";
  image.height = 2;
  image.step = 3;
  image.data.resize(6);
  EXPECT_EQ(ecsr::malformedImage(image), "");
}

TEST(ProbeUri, TellsAListeningPortFromAClosedOne) {
  const int fd = socket(AF_INET, SOCK_STREAM, 0);
  ASSERT_GE(fd, 0);
  sockaddr_in address{};
  address.sin_family = AF_INET;
  address.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  address.sin_port = 0;
  ASSERT_EQ(bind(fd, reinterpret_cast<sockaddr*>(&address), sizeof(address)), 0);
  ASSERT_EQ(listen(fd, 4), 0);
  socklen_t length = sizeof(address);
  ASSERT_EQ(getsockname(fd, reinterpret_cast<sockaddr*>(&address), &length), 0);
  const std::string uri = "http://127.0.0.1:" + std::to_string(ntohs(address.sin_port)) + "/";
  EXPECT_EQ(ecsr::probeUri(uri, 1.0), ecsr::CallerState::kRunning);
  close(fd);  // nothing listens there now
  EXPECT_EQ(ecsr::probeUri(uri, 1.0), ecsr::CallerState::kGone);
  EXPECT_EQ(ecsr::probeUri("not a uri", 1.0), ecsr::CallerState::kUnknown);
}
