#pragma once
// The start-up every nodelet of this package shares: initialise() reads and checks the
// parameters and wires topics, services and timers. When it throws, the nodelet logs a FATAL
// line naming itself and the problem, releaseAfterFailedStart() unregisters whatever
// initialise() had already set up (the manager frees a failed nodelet's callback queues before
// its destructor runs), and the exception goes on to the manager, which refuses the nodelet.
// Parameters and their errors: docs/nodelets.md.
//
// Threading: onInit() runs once, on the manager's loading thread.
#include <exception>

#include <nodelet/nodelet.h>

namespace embedded_calibration_stereo {

class GuardedNodelet : public nodelet::Nodelet {
 protected:
  // `display_name`: how log lines name the nodelet ("Separator cannot start: ...").
  explicit GuardedNodelet(const char* display_name) : display_name_(display_name) {}

  // Reads the parameters and sets the nodelet up; throws (ConfigError for a bad parameter) when
  // it cannot run.
  virtual void initialise() = 0;
  // Undoes what a failed initialise() may have registered; the default has nothing to undo.
  virtual void releaseAfterFailedStart() {}

 private:
  void onInit() final {
    try {
      initialise();
    } catch (const std::exception& e) {
      NODELET_FATAL("%s cannot start: %s", display_name_, e.what());
      releaseAfterFailedStart();
      throw;
    }
  }

  const char* display_name_;
};

}  // namespace embedded_calibration_stereo
