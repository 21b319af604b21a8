#pragma once
/// \file cli.h
/// \brief What every pcl_* tool shares: a strict command-line parser (unknown or
/// malformed flags are errors, `-h` lists every flag with its default), exit codes
/// and a progress bar on stderr.

#include <chrono>
#include <cstddef>
#include <exception>
#include <functional>
#include <stdexcept>
#include <string>
#include <vector>

namespace pcl_rast_tools {

/// \brief Process exit codes shared by all tools.
enum ExitCode : int
{
  kExitOk = 0,
  kExitBadArguments = 1,
  kExitIoError = 2,
  kExitAlgorithmFailure = 3
};

/// \brief Thrown by ArgParser::parse on an unknown, repeated, missing or malformed flag.
class ArgumentError : public std::runtime_error
{
public:
  using std::runtime_error::runtime_error;
};

/// \brief PCL-style flags (`-name value`, `-switch`), validated strictly.
/// Each option is bound to a variable whose current value is the documented default.
class ArgParser
{
public:
  ArgParser(std::string program, std::string description);

  /// \brief A switch without a value: `-name` sets *out to true.
  void addSwitch(const std::string& name, const std::string& help, bool* out);
  void addString(const std::string& name, const std::string& help, std::string* out,
                 bool required = false);
  /// \brief A string restricted to \a choices.
  void addChoice(const std::string& name, const std::string& help, std::string* out,
                 const std::vector<std::string>& choices);
  void addInt(const std::string& name, const std::string& help, int* out,
              bool required = false);
  void addDouble(const std::string& name, const std::string& help, double* out,
                 bool required = false);
  /// \brief A positional argument (in order of declaration); required unless \a optional.
  void addPositional(const std::string& name, const std::string& help, std::string* out,
                     bool optional = false);

  /// \brief Parse argv. Returns false when `-h`/`--help` was given (usage printed
  /// to stdout); the tool should then exit with kExitOk.
  /// \throws ArgumentError naming the offending flag or value.
  bool parse(int argc, char** argv);

  /// \brief Whether the flag was given explicitly on the command line.
  bool given(const std::string& name) const;

  std::string usage() const;

private:
  struct Option
  {
    std::string name, help, default_text, kind;
    bool required = false, takes_value = true, given = false;
    std::function<void(const std::string&)> assign;
  };
  Option* find(const std::string& name);
  const Option* find(const std::string& name) const;

  std::string program_, description_;
  std::vector<Option> options_;
  std::vector<Option> positionals_;
};

/// \brief Run a tool's body with SIGPIPE ignored: ArgumentError -> usage hint and exit 1,
/// std::invalid_argument -> exit 1, other std::exception -> exit 2 (I/O),
/// each printed as "program: error: ..." on stderr.
int runTool(const std::string& program, const std::function<int()>& body);

/// \brief Peak resident memory of the process so far [MB].
double peakRssMb();

/// \brief User + system CPU time of the whole process so far [s].
double processCpuS();

/// \brief The what() of a stored exception ("unknown error" for a non-std one).
std::string exceptionMessage(const std::exception_ptr& error);

/// \brief A fault to inject, for the tests of the error paths (doc/slam.md, Errors): the
/// environment variable PCL_RAST_INJECT_FAULT="<stage>:<n>" makes a tool throw a
/// std::runtime_error when <stage> (tracking: frame n; local_mapping, loop_closing:
/// key-frame n) reaches n. Unset: no fault.
struct InjectedFault
{
  std::string stage;
  std::size_t index = 0;
  bool active = false;
  /// \brief Throws "injected fault (PCL_RAST_INJECT_FAULT=...)" when \a stage reaches
  /// the fault's index.
  void check(const std::string& stage_name, std::size_t index_now) const;
};

/// \brief The fault PCL_RAST_INJECT_FAULT asks for, checked against \a stages.
/// \throws ArgumentError on a malformed value or an unknown stage.
InjectedFault injectedFault(const std::vector<std::string>& stages);

/// \brief A progress bar on stderr: `label [=====>    ] 120/4541  35.2 fps  ETA 2:05`.
/// On a terminal it redraws in place; otherwise it prints a line every 10 %.
class ProgressBar
{
public:
  ProgressBar(std::string label, std::size_t total);
  ~ProgressBar();
  void update(std::size_t done);
  void finish();

private:
  std::string label_;
  std::size_t total_;
  bool tty_;
  bool finished_ = false;
  int last_decile_ = -1;
  std::chrono::steady_clock::time_point start_, last_draw_;
};

} // namespace pcl_rast_tools
