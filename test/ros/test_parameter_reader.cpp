// ParameterReader over a map of XmlRpc values (no master): the type rules (XmlRpc: an int only
// from an int, a double from an int or a finite double, a bool only from a bool, a string only
// from a string), defaults for absent parameters, required parameters and the range and choice
// checks, each refusal naming the parameter. The NodeHandle path is exercised by the nodelets'
// rostest (nodelet_bad_config).
#include <gtest/gtest.h>

#include <limits>
#include <map>
#include <memory>
#include <string>
#include <vector>

#include "embedded_calibration_stereo/parameter_table.h"
#include "embedded_calibration_stereo/ros/parameter_reader.h"

namespace core = embedded_calibration_stereo::core;

using embedded_calibration_stereo::ParameterReader;
using XmlRpc::XmlRpcValue;

namespace {

using Params = embedded_calibration_stereo::test_support::ParameterTable;

// The message of the ConfigError `f` throws, after checking it names `parameter`.
template <class F>
std::string refusal(const std::string& parameter, F f) {
  try {
    f();
  } catch (const core::ConfigError& e) {
    EXPECT_EQ(e.parameter(), parameter);
    EXPECT_EQ(std::string(e.what()).rfind(parameter + ": ", 0), 0u) << e.what();
    return e.what();
  }
  ADD_FAILURE() << parameter << " was not refused";
  return "";
}

XmlRpcValue list() {
  XmlRpcValue v;
  v.setSize(1);
  v[0] = 1;
  return v;
}

}  // namespace

TEST(ParameterReader, AbsentParametersTakeTheirDefault) {
  const Params none;
  const ParameterReader read = none.reader();
  EXPECT_EQ(read.get("queue_size", 7), 7);
  EXPECT_EQ(read.get("fps", 12.5), 12.5);
  EXPECT_EQ(read.get("approximate_sync", true), true);
  EXPECT_EQ(read.get("approximate_sync", false), false);
  EXPECT_EQ(read.get("method", "bouguet"), "bouguet");
  EXPECT_EQ(read.get<std::string>("method", "fusiello"), "fusiello");
  EXPECT_FALSE(read.has("queue_size"));
}

TEST(ParameterReader, PresentValuesOfTheRightTypeAreRead) {
  Params p;
  p.set("queue_size", 3).set("fps", 7.5).set("approximate_sync", true).set("method", std::string("fusiello"));
  const ParameterReader read = p.reader();
  EXPECT_TRUE(read.has("queue_size"));
  EXPECT_EQ(read.get("queue_size", 5), 3);
  EXPECT_EQ(read.get("fps", 30.0), 7.5);
  EXPECT_EQ(read.get("approximate_sync", false), true);
  EXPECT_EQ(read.get("method", "bouguet"), "fusiello");
  // Negative and zero values are values, not "absent".
  p.set("queue_size", 0).set("fps", -2.0).set("approximate_sync", false);
  EXPECT_EQ(p.reader().get("queue_size", 5), 0);
  EXPECT_EQ(p.reader().get("fps", 30.0), -2.0);
  EXPECT_EQ(p.reader().get("approximate_sync", true), false);
}

// An integer parameter is an XmlRpc int: 5.0 is refused (roscpp's getParam(int) would round it),
// so are strings, booleans and lists.
TEST(ParameterReader, IntegerOnlyFromAnInteger) {
  Params p;
  p.set("queue_size", 5.0).set("teach_frames", std::string("five")).set("settle_frames", true);
  p.set("gpio_line", 4.6).set("v4l2_width", list());
  const ParameterReader read = p.reader();
  const std::string m = refusal("queue_size", [&] { read.get("queue_size", 1); });
  EXPECT_NE(m.find("must be an integer"), std::string::npos) << m;
  EXPECT_NE(m.find("5.0"), std::string::npos) << m;
  EXPECT_NE(refusal("teach_frames", [&] { read.get("teach_frames", 1); }).find("the string 'five'"),
            std::string::npos);
  EXPECT_NE(refusal("settle_frames", [&] { read.get("settle_frames", 1); }).find("the boolean true"),
            std::string::npos);
  EXPECT_NE(refusal("gpio_line", [&] { read.get("gpio_line", 1); }).find("4.6"), std::string::npos);
  EXPECT_NE(refusal("v4l2_width", [&] { read.get("v4l2_width", 1); }).find("a list"), std::string::npos);
}

// A double parameter accepts an XmlRpc int (fps: 30) and a finite double, nothing else.
TEST(ParameterReader, NumberFromAnIntegerOrAFiniteDouble) {
  Params p;
  p.set("fps", 30).set("scale", -0.25).set("text", std::string("fast")).set("flag", false);
  p.set("nan", std::numeric_limits<double>::quiet_NaN()).set("inf", std::numeric_limits<double>::infinity());
  const ParameterReader read = p.reader();
  const double fps = read.get("fps", 1.5);
  EXPECT_EQ(fps, 30.0);
  EXPECT_EQ(read.get("scale", 1.0), -0.25);
  EXPECT_NE(refusal("text", [&] { read.get("text", 1.0); }).find("must be a number"), std::string::npos);
  refusal("flag", [&] { read.get("flag", 1.0); });
  EXPECT_NE(refusal("nan", [&] { read.get("nan", 1.0); }).find("finite"), std::string::npos);
  EXPECT_NE(refusal("inf", [&] { read.get("inf", 1.0); }).find("finite"), std::string::npos);
}

TEST(ParameterReader, BoolOnlyFromABool) {
  Params p;
  p.set("one", 1).set("zero", 0).set("word", std::string("true")).set("real", 1.0);
  const ParameterReader read = p.reader();
  for (const char* name : {"one", "zero", "word", "real"}) {
    const std::string m = refusal(name, [&] { read.get(name, false); });
    EXPECT_NE(m.find("must be true or false"), std::string::npos) << m;
  }
}

TEST(ParameterReader, StringOnlyFromAString) {
  Params p;
  p.set("method", 3).set("frame", true).set("path", 1.5);
  const ParameterReader read = p.reader();
  for (const char* name : {"method", "frame", "path"}) {
    const std::string m = refusal(name, [&] { read.get(name, "x"); });
    EXPECT_NE(m.find("must be a string"), std::string::npos) << m;
  }
}

TEST(ParameterReader, RequiredParameters) {
  Params p;
  p.set("serial_port", std::string("/dev/ttyUSB0")).set("baud", std::string("fast"));
  const ParameterReader read = p.reader();
  EXPECT_EQ(read.required<std::string>("serial_port"), "/dev/ttyUSB0");
  EXPECT_NE(refusal("device", [&] { read.required<std::string>("device"); }).find("missing"), std::string::npos);
  EXPECT_NE(refusal("count", [&] { read.required<int>("count"); }).find("missing"), std::string::npos);
  EXPECT_NE(refusal("baud", [&] { read.required<int>("baud"); }).find("must be an integer"), std::string::npos);
}

// Ranges are closed; a default outside the range is refused too (it is the value in force).
TEST(ParameterReader, RangeChecks) {
  Params p;
  p.set("low", 1).set("high", 10).set("below", 0).set("above", 11).set("ratio", 1.5).set("negative", -0.5);
  const ParameterReader read = p.reader();
  EXPECT_EQ(read.inRange("low", 5, 1, 10), 1);
  EXPECT_EQ(read.inRange("high", 5, 1, 10), 10);
  EXPECT_EQ(read.inRange("absent", 5, 1, 10), 5);
  const std::string below = refusal("below", [&] { read.inRange("below", 5, 1, 10); });
  EXPECT_NE(below.find("[1, 10]"), std::string::npos) << below;
  EXPECT_NE(below.find("got 0"), std::string::npos) << below;
  refusal("above", [&] { read.inRange("above", 5, 1, 10); });
  refusal("absent", [&] { read.inRange("absent", 0, 1, 10); });
  EXPECT_EQ(read.inRange("ratio", 0.5, 0.0, 1.5), 1.5);
  refusal("ratio", [&] { read.inRange("ratio", 0.5, 0.0, 1.0); });

  EXPECT_EQ(read.atLeast("low", 5, 1), 1);
  const std::string m = refusal("below", [&] { read.atLeast("below", 5, 1); });
  EXPECT_NE(m.find("must be >= 1, got 0"), std::string::npos) << m;
  refusal("negative", [&] { read.atLeast("negative", 1.0, 0.0); });
  EXPECT_EQ(read.atLeast("ratio", 1.0, 0.0), 1.5);
}

TEST(ParameterReader, ChoiceChecks) {
  Params p;
  p.set("backend", std::string("v4l2")).set("light", std::string("laser")).set("method", 2);
  const ParameterReader read = p.reader();
  EXPECT_EQ(read.choice("backend", "sim", {"sim", "files", "v4l2"}), "v4l2");
  EXPECT_EQ(read.choice("absent", "sim", {"sim", "files", "v4l2"}), "sim");
  const std::string m = refusal("light", [&] { read.choice("light", "none", {"sim", "serial", "gpio", "none"}); });
  EXPECT_NE(m.find("'laser'"), std::string::npos) << m;
  EXPECT_NE(m.find("sim, serial, gpio or none"), std::string::npos) << m;
  EXPECT_NE(refusal("method", [&] { read.choice("method", "a", {"a", "b"}); }).find("must be a string"),
            std::string::npos);
}

// checkReconfigureTypes against a Config with the generated API (__getParamDescriptions__ of
// dynamic_reconfigure's type names).
namespace {
struct Description {
  std::string name, type;
};
struct FakeConfig {
  static std::vector<std::shared_ptr<const Description>> __getParamDescriptions__() {
    return {std::make_shared<Description>(Description{"range", "int"}),
            std::make_shared<Description>(Description{"ratio", "double"}),
            std::make_shared<Description>(Description{"algorithm", "str"}),
            std::make_shared<Description>(Description{"subpixel", "bool"})};
  }
};
}  // namespace

TEST(ParameterReader, ReconfigureTypes) {
  Params good;
  good.set("range", 64).set("ratio", 5).set("algorithm", std::string("sgbm")).set("subpixel", false);
  embedded_calibration_stereo::checkReconfigureTypes<FakeConfig>(good.reader());
  embedded_calibration_stereo::checkReconfigureTypes<FakeConfig>(Params().reader());  // all absent

  const std::vector<std::pair<std::string, XmlRpcValue>> bad = {
      {"range", XmlRpcValue(std::string("sixty"))},
      {"range", XmlRpcValue(64.0)},
      {"ratio", XmlRpcValue(true)},
      {"algorithm", XmlRpcValue(1)},
      {"subpixel", XmlRpcValue(1)}};
  for (const auto& b : bad) {
    Params p = good;
    p.set(b.first, b.second);
    refusal(b.first, [&] { embedded_calibration_stereo::checkReconfigureTypes<FakeConfig>(p.reader()); });
  }
  refusal("x", [&] { good.reader().checkType("x", "float"); });
}
