#include "cli.h"

#include <sys/resource.h>
#include <unistd.h>

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <csignal>
#include <iomanip>
#include <iostream>
#include <limits>
#include <sstream>

namespace pcl_rast_tools {

namespace {

double
parseDouble(const std::string& flag, const std::string& text)
{
  std::size_t used = 0;
  double value = 0.0;
  try {
    value = std::stod(text, &used);
  }
  catch (const std::exception&) {
    used = 0;
  }
  if (used != text.size() || !std::isfinite(value))
    throw ArgumentError("-" + flag + " expects a number, got '" + text + "'");
  return value;
}

int
parseInt(const std::string& flag, const std::string& text)
{
  std::size_t used = 0;
  long value = 0;
  try {
    value = std::stol(text, &used);
  }
  catch (const std::exception&) {
    used = 0;
  }
  if (used != text.size() || value < std::numeric_limits<int>::min() ||
      value > std::numeric_limits<int>::max())
    throw ArgumentError("-" + flag + " expects an integer, got '" + text + "'");
  return static_cast<int>(value);
}

std::string
formatDouble(double value)
{
  std::ostringstream out;
  out << value;
  return out.str();
}

} // namespace

ArgParser::ArgParser(std::string program, std::string description)
: program_(std::move(program)), description_(std::move(description))
{}

void
ArgParser::addSwitch(const std::string& name, const std::string& help, bool* out)
{
  Option option;
  option.name = name;
  option.help = help;
  option.kind = "";
  option.takes_value = false;
  // A switch is off unless given: it has no default worth printing.
  option.default_text = "";
  option.assign = [out](const std::string&) { *out = true; };
  options_.push_back(std::move(option));
}

void
ArgParser::addString(const std::string& name,
                     const std::string& help,
                     std::string* out,
                     bool required)
{
  Option option;
  option.name = name;
  option.help = help;
  option.kind = "<string>";
  option.required = required;
  option.default_text = out->empty() ? "" : *out;
  option.assign = [out](const std::string& value) { *out = value; };
  options_.push_back(std::move(option));
}

void
ArgParser::addChoice(const std::string& name,
                     const std::string& help,
                     std::string* out,
                     const std::vector<std::string>& choices)
{
  Option option;
  option.name = name;
  option.help = help;
  std::string kind;
  for (const auto& choice : choices)
    kind += (kind.empty() ? "" : "|") + choice;
  option.kind = "<" + kind + ">";
  option.default_text = *out;
  option.assign = [out, choices, name](const std::string& value) {
    for (const auto& choice : choices)
      if (choice == value) {
        *out = value;
        return;
      }
    std::string list;
    for (const auto& choice : choices)
      list += (list.empty() ? "" : ", ") + choice;
    throw ArgumentError("-" + name + " must be one of " + list + ", got '" + value + "'");
  };
  options_.push_back(std::move(option));
}

void
ArgParser::addInt(const std::string& name, const std::string& help, int* out, bool required)
{
  Option option;
  option.name = name;
  option.help = help;
  option.kind = "<int>";
  option.required = required;
  option.default_text = std::to_string(*out);
  option.assign = [out, name](const std::string& value) { *out = parseInt(name, value); };
  options_.push_back(std::move(option));
}

void
ArgParser::addDouble(const std::string& name,
                     const std::string& help,
                     double* out,
                     bool required)
{
  Option option;
  option.name = name;
  option.help = help;
  option.kind = "<number>";
  option.required = required;
  option.default_text = formatDouble(*out);
  option.assign = [out, name](const std::string& value) {
    *out = parseDouble(name, value);
  };
  options_.push_back(std::move(option));
}

void
ArgParser::addPositional(const std::string& name,
                         const std::string& help,
                         std::string* out,
                         bool optional)
{
  Option option;
  option.name = name;
  option.help = help;
  option.required = !optional;
  option.assign = [out](const std::string& value) { *out = value; };
  positionals_.push_back(std::move(option));
}

ArgParser::Option*
ArgParser::find(const std::string& name)
{
  for (auto& option : options_)
    if (option.name == name)
      return &option;
  return nullptr;
}

const ArgParser::Option*
ArgParser::find(const std::string& name) const
{
  for (const auto& option : options_)
    if (option.name == name)
      return &option;
  return nullptr;
}

bool
ArgParser::parse(int argc, char** argv)
{
  std::size_t next_positional = 0;
  for (int i = 1; i < argc; ++i) {
    const std::string arg = argv[i];
    if (arg == "-h" || arg == "--help" || arg == "-help") {
      std::cout << usage();
      return false;
    }
    // A lone '-' or a negative number is a value, not a flag.
    const bool looks_like_flag =
        arg.size() > 1 && arg[0] == '-' &&
        !(std::isdigit(static_cast<unsigned char>(arg[1])) || arg[1] == '.');
    if (looks_like_flag) {
      const std::string name = arg.substr(arg[1] == '-' ? 2 : 1);
      Option* option = find(name);
      if (!option)
        throw ArgumentError("unknown flag '" + arg + "' (see -h)");
      if (option->given)
        throw ArgumentError("flag '" + arg + "' given twice");
      option->given = true;
      if (!option->takes_value) {
        option->assign("");
        continue;
      }
      if (i + 1 >= argc)
        throw ArgumentError("flag '" + arg + "' expects a value " + option->kind);
      option->assign(argv[++i]);
      continue;
    }
    if (next_positional >= positionals_.size())
      throw ArgumentError("unexpected argument '" + arg + "' (see -h)");
    positionals_[next_positional].given = true;
    positionals_[next_positional++].assign(arg);
  }
  for (const auto& positional : positionals_)
    if (positional.required && !positional.given)
      throw ArgumentError("missing argument " + positional.name + " (see -h)");
  for (const auto& option : options_)
    if (option.required && !option.given)
      throw ArgumentError("missing required flag -" + option.name + " (see -h)");
  return true;
}

bool
ArgParser::given(const std::string& name) const
{
  const Option* option = find(name);
  if (option)
    return option->given;
  for (const auto& positional : positionals_)
    if (positional.name == name)
      return positional.given;
  return false;
}

std::string
ArgParser::usage() const
{
  std::ostringstream out;
  out << description_ << "\n\nUsage: " << program_;
  for (const auto& positional : positionals_)
    out << (positional.required ? " " : " [") << positional.name
        << (positional.required ? "" : "]");
  out << " [options]\n";
  if (!positionals_.empty()) {
    out << "\nArguments:\n";
    for (const auto& positional : positionals_)
      out << "  " << std::left << std::setw(26) << positional.name << positional.help << "\n";
  }
  out << "\nOptions:\n";
  for (const auto& option : options_) {
    const std::string flag = "-" + option.name + (option.kind.empty() ? "" : " " + option.kind);
    out << "  " << std::left << std::setw(26) << flag;
    if (flag.size() >= 26)
      out << "\n  " << std::string(26, ' ');
    out << option.help;
    if (option.required)
      out << " (required)";
    else if (!option.default_text.empty())
      out << " (default: " << option.default_text << ")";
    out << "\n";
  }
  out << "  " << std::left << std::setw(26) << "-h" << "print this help\n";
  return out.str();
}

int
runTool(const std::string& program, const std::function<int()>& body)
{
  // A closed pipe on stdout/stderr (`tool ... | head`) fails those writes; it never
  // kills a run (long-running tools also take SIGINT/TERM/HUP: stop_signals.h).
  std::signal(SIGPIPE, SIG_IGN);
  try {
    return body();
  }
  catch (const ArgumentError& e) {
    std::cerr << program << ": error: " << e.what() << "\n";
    return kExitBadArguments;
  }
  catch (const std::invalid_argument& e) {
    std::cerr << program << ": error: " << e.what() << "\n";
    return kExitBadArguments;
  }
  catch (const std::exception& e) {
    std::cerr << program << ": error: " << e.what() << "\n";
    return kExitIoError;
  }
}

double
peakRssMb()
{
  rusage usage{};
  getrusage(RUSAGE_SELF, &usage);
  return usage.ru_maxrss / 1024.0; // Linux: kilobytes
}

double
processCpuS()
{
  rusage usage{};
  getrusage(RUSAGE_SELF, &usage);
  return usage.ru_utime.tv_sec + usage.ru_stime.tv_sec +
         1e-6 * (usage.ru_utime.tv_usec + usage.ru_stime.tv_usec);
}

std::string
exceptionMessage(const std::exception_ptr& error)
{
  try {
    std::rethrow_exception(error);
  } catch (const std::exception& e) {
    return e.what();
  } catch (...) {
    return "unknown error";
  }
}

InjectedFault
injectedFault(const std::vector<std::string>& stages)
{
  InjectedFault fault;
  const char* value = std::getenv("PCL_RAST_INJECT_FAULT");
  if (!value || !*value)
    return fault;
  const std::string text(value);
  const auto colon = text.find(':');
  const std::string stage = text.substr(0, colon);
  bool known = false;
  for (const auto& s : stages)
    known = known || s == stage;
  std::size_t used = 0;
  long long index = -1;
  if (colon != std::string::npos) {
    try {
      index = std::stoll(text.substr(colon + 1), &used);
    } catch (const std::exception&) {
      used = 0;
    }
  }
  if (!known || colon == std::string::npos || used == 0 ||
      used != text.size() - colon - 1 || index < 0)
    throw ArgumentError("PCL_RAST_INJECT_FAULT='" + text +
                        "' is not <stage>:<n> with a stage of this tool and n >= 0");
  fault.stage = stage;
  fault.index = static_cast<std::size_t>(index);
  fault.active = true;
  return fault;
}

void
InjectedFault::check(const std::string& stage_name, std::size_t index_now) const
{
  if (active && stage_name == stage && index_now == index)
    throw std::runtime_error("injected fault (PCL_RAST_INJECT_FAULT=" + stage + ":" +
                             std::to_string(index) + ")");
}

ProgressBar::ProgressBar(std::string label, std::size_t total)
: label_(std::move(label))
, total_(total)
, tty_(::isatty(STDERR_FILENO) != 0)
, start_(std::chrono::steady_clock::now())
, last_draw_(start_ - std::chrono::seconds(1))
{}

ProgressBar::~ProgressBar()
{
  if (!finished_)
    finish();
}

void
ProgressBar::update(std::size_t done)
{
  using namespace std::chrono;
  const auto now = steady_clock::now();
  const double elapsed_s = duration<double>(now - start_).count();
  const double fraction = total_ ? std::min(1.0, double(done) / double(total_)) : 1.0;
  const double rate = elapsed_s > 0 ? double(done) / elapsed_s : 0.0;
  const double eta_s = rate > 0 ? double(total_ - std::min(done, total_)) / rate : 0.0;
  char eta[32];
  std::snprintf(eta, sizeof(eta), "%d:%02d", int(eta_s) / 60, int(eta_s) % 60);

  if (tty_) {
    if (now - last_draw_ < milliseconds(100) && done < total_)
      return;
    last_draw_ = now;
    const int width = 30;
    const int filled = int(fraction * width);
    std::string bar(width, ' ');
    for (int i = 0; i < filled; ++i)
      bar[i] = '=';
    if (filled < width)
      bar[filled] = '>';
    std::fprintf(stderr, "\r%s [%s] %zu/%zu %6.1f fps  ETA %s ", label_.c_str(), bar.c_str(),
                 done, total_, rate, eta);
    std::fflush(stderr);
    return;
  }
  const int decile = int(fraction * 10.0);
  if (decile > last_decile_) {
    last_decile_ = decile;
    std::fprintf(stderr, "%s: %3d%% (%zu/%zu, %.1f fps, ETA %s)\n", label_.c_str(),
                 decile * 10, done, total_, rate, eta);
  }
}

void
ProgressBar::finish()
{
  if (finished_)
    return;
  finished_ = true;
  const double elapsed_s =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start_).count();
  if (tty_)
    std::fprintf(stderr, "\n");
  std::fprintf(stderr, "%s [done, %.1f s]\n", label_.c_str(), elapsed_s);
}

} // namespace pcl_rast_tools
