// The tools' shared command-line parser: strict flags, defaults, errors.
#include "cli.h"
#include "stop_signals.h"

#include <gtest/gtest.h>

#include <csignal>
#include <optional>
#include <string>
#include <sys/wait.h>
#include <unistd.h>
#include <vector>

// This file's names stay its own: a test program compiles several test files as
// one translation unit (test/CMakeLists.txt).
namespace test_cli {

namespace {

using pcl_rast_tools::ArgParser;
using pcl_rast_tools::ArgumentError;

/// Runs parse() on a list of arguments (argv[0] is added).
bool
parseArgs(ArgParser& parser, std::vector<std::string> args)
{
  args.insert(args.begin(), "pcl_test");
  std::vector<char*> argv;
  for (auto& arg : args)
    argv.push_back(arg.data());
  return parser.parse(static_cast<int>(argv.size()), argv.data());
}

struct Flags
{
  std::string input;
  std::string format = "bin";
  int first = 0;
  double leaf_m = 0.25;
  bool json = false;
};

ArgParser
makeParser(Flags& flags)
{
  ArgParser parser("pcl_test", "A test tool.");
  parser.addString("input", "input folder", &flags.input, true);
  parser.addChoice("format", "scan format", &flags.format, {"bin", "pcd"});
  parser.addInt("first", "first frame", &flags.first);
  parser.addDouble("leaf", "voxel leaf size in metres", &flags.leaf_m);
  parser.addSwitch("json", "print JSON", &flags.json);
  return parser;
}

} // namespace

TEST(ArgParser, ParsesAllKinds)
{
  Flags flags;
  ArgParser parser = makeParser(flags);
  ASSERT_TRUE(parseArgs(parser, {"-input", "dir", "-format", "pcd", "-first", "-3", "-leaf",
                                 "0.5", "-json"}));
  EXPECT_EQ(flags.input, "dir");
  EXPECT_EQ(flags.format, "pcd");
  EXPECT_EQ(flags.first, -3);
  EXPECT_DOUBLE_EQ(flags.leaf_m, 0.5);
  EXPECT_TRUE(flags.json);
  EXPECT_TRUE(parser.given("leaf"));
}

TEST(ArgParser, KeepsDefaultsAndListsThemInUsage)
{
  Flags flags;
  ArgParser parser = makeParser(flags);
  ASSERT_TRUE(parseArgs(parser, {"-input", "dir"}));
  EXPECT_EQ(flags.format, "bin");
  EXPECT_DOUBLE_EQ(flags.leaf_m, 0.25);
  EXPECT_FALSE(parser.given("leaf"));
  const std::string usage = parser.usage();
  EXPECT_NE(usage.find("-leaf <number>"), std::string::npos) << usage;
  EXPECT_NE(usage.find("(default: 0.25)"), std::string::npos) << usage;
  EXPECT_NE(usage.find("(required)"), std::string::npos) << usage;
}

TEST(ArgParser, RejectsBadInput)
{
  const std::vector<std::vector<std::string>> bad = {
      {"-input", "dir", "-unknown"},       // unknown flag
      {"-format", "bin"},                  // missing required flag
      {"-input", "dir", "-first", "1.5"},  // not an integer
      {"-input", "dir", "-leaf", "abc"},   // not a number
      {"-input", "dir", "-format", "ply"}, // not a choice
      {"-input"},                          // missing value
      {"-input", "a", "-input", "b"},      // repeated
      {"-input", "a", "stray"},            // unexpected positional
  };
  for (const auto& args : bad) {
    Flags flags;
    ArgParser parser = makeParser(flags);
    EXPECT_THROW(parseArgs(parser, args), ArgumentError) << args.back();
  }
}

TEST(ArgParser, HelpReturnsFalse)
{
  Flags flags;
  ArgParser parser = makeParser(flags);
  testing::internal::CaptureStdout();
  EXPECT_FALSE(parseArgs(parser, {"-h"}));
  const std::string out = testing::internal::GetCapturedStdout();
  EXPECT_NE(out.find("Usage: pcl_test"), std::string::npos);
}

TEST(ArgParser, Positionals)
{
  std::string est, gt, extra;
  ArgParser parser("pcl_eval", "Evaluate.");
  parser.addPositional("EST", "estimate", &est);
  parser.addPositional("GT", "ground truth", &gt);
  parser.addPositional("EXTRA", "optional", &extra, true);
  ASSERT_TRUE(parseArgs(parser, {"a.txt", "b.txt"}));
  EXPECT_EQ(est, "a.txt");
  EXPECT_EQ(gt, "b.txt");
  EXPECT_TRUE(extra.empty());
  ArgParser missing("pcl_eval", "Evaluate.");
  missing.addPositional("EST", "estimate", &est);
  missing.addPositional("GT", "ground truth", &gt);
  EXPECT_THROW(parseArgs(missing, {"a.txt"}), ArgumentError);
}

TEST(RunTool, MapsExceptionsToExitCodes)
{
  using namespace pcl_rast_tools;
  testing::internal::CaptureStderr();
  EXPECT_EQ(runTool("t", [] { return 0; }), kExitOk);
  EXPECT_EQ(runTool("t", []() -> int { throw ArgumentError("x"); }), kExitBadArguments);
  EXPECT_EQ(runTool("t", []() -> int { throw std::invalid_argument("x"); }), kExitBadArguments);
  EXPECT_EQ(runTool("t", []() -> int { throw std::runtime_error("disk"); }), kExitIoError);
  const std::string err = testing::internal::GetCapturedStderr();
  EXPECT_NE(err.find("t: error: disk"), std::string::npos) << err;
}

/// A second stop signal while the outputs are moved into place (DeferStopExit alive)
/// ends the process only once they are all moved; without the guard it ends at once.
/// Each case runs in a child process: the handlers are process-wide.
TEST(StopSignals, ASecondSignalWaitsForTheOutputsToBeMoved)
{
  const auto child = [](bool guarded) {
    int fds[2];
    if (::pipe(fds) != 0)
      return std::make_pair(-1, std::string());
    const pid_t pid = ::fork();
    if (pid == 0) {
      ::close(fds[0]);
      pcl_rast_tools::installStopSignals();
      std::raise(SIGTERM); // the first: a stop request
      if (!pcl_rast_tools::stopRequested())
        ::_exit(10);
      {
        std::optional<pcl_rast_tools::DeferStopExit> defer;
        if (guarded)
          defer.emplace();
        std::raise(SIGTERM); // the second, "while publishing"
        (void)!::write(fds[1], "moved", 5); // reached only when the exit waits
      }
      ::_exit(0); // never reached when a second signal came
    }
    ::close(fds[1]);
    std::string out;
    char buf[16];
    for (ssize_t n; (n = ::read(fds[0], buf, sizeof buf)) > 0;)
      out.append(buf, static_cast<std::size_t>(n));
    ::close(fds[0]);
    int status = 0;
    ::waitpid(pid, &status, 0);
    return std::make_pair(WIFEXITED(status) ? WEXITSTATUS(status) : -1, out);
  };
  const auto guarded = child(true);
  EXPECT_EQ(guarded.first, 128 + SIGTERM);
  EXPECT_EQ(guarded.second, "moved");
  const auto unguarded = child(false);
  EXPECT_EQ(unguarded.first, 128 + SIGTERM);
  EXPECT_EQ(unguarded.second, "");
}

} // namespace test_cli
