#pragma once
// A parameter server in a map, for tests of code that reads parameters through ParameterReader
// (no master needed). Header-only: the test support library does not link the ROS glue.
#include <map>
#include <string>

#include <xmlrpcpp/XmlRpcValue.h>

#include "embedded_calibration_stereo/ros/parameter_reader.h"

namespace embedded_calibration_stereo::test_support {

class ParameterTable {
 public:
  ParameterTable& set(const std::string& name, const XmlRpc::XmlRpcValue& value) {
    values_[name] = value;
    return *this;
  }
  // The reader refers to this object: keep it alive while reading.
  ParameterReader reader() const {
    return ParameterReader([this](const std::string& name, XmlRpc::XmlRpcValue* value) {
      const auto it = values_.find(name);
      if (it == values_.end()) return false;
      *value = it->second;
      return true;
    });
  }

 private:
  std::map<std::string, XmlRpc::XmlRpcValue> values_;
};

}  // namespace embedded_calibration_stereo::test_support
