#!/usr/bin/env bash
# The sanitizer checks CI runs after the README's tests (issue 12), sized to keep the
# whole CI under 30 minutes on a slow 2-core machine (doc/slam.md, "Fuzzing,
# sanitizers and signal checks"):
#   - asan: an ASan + UBSan build of the libraries and tools, run by the test programs
#     (their own code uninstrumented) that feed them hostile input, write and read
#     files, spill and reload maps, run the tools and the SLAM end to end; their tests
#     run but for the long simulated drives that measure accuracy (those run in the
#     README's Release suite). UBSan keeps the checks ASan cannot make (integer and
#     shift UB, conversions, bool/enum loads, bounds, unreachable code); ASan itself
#     catches the bad pointers that UBSan's costlier pointer checks would.
#   - asan-full: ASan with all of UBSan (gcc's undefined group and float-cast-overflow)
#     on every test program, the tests' own code under ASan too, running the whole
#     suite (as CI did until session 27). Run it before landing a change to
#     memory-heavy code that the focused set does not reach.
#   - tsan: a TSan build runs the threaded SLAM tests (RastSlam.* in threaded mode, the
#     pcl_rast_slam tool, local mapping, the background placements of MapLocalization).
# Every report halts its test (halt_on_error); the only suppressions are for the named
# third-party libraries in scripts/sanitizers/*.supp. One library of the project is built
# without the sanitizers: the simulator (simulation/CMakeLists.txt), the test bed (its
# ray casting alone was a third of the sanitized suite's time in session 15).
#
#   scripts/run_sanitizers.sh [asan|asan-full|tsan]...   (default: asan tsan)
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
kinds=("$@")
[ ${#kinds[@]} -eq 0 ] && kinds=(asan tsan)
supp="$root/scripts/sanitizers"
jobs="$(nproc)"

# Everything builds at -O1. Not -O0 for the tests' own code: it compiles a test file a
# quarter faster under ASan, but tests that loop over clouds with Eigen in their own
# code then run 8-23 times slower (Odometry.SimulatedDriveHasSmallDrift... 35 -> 461 s).
# Ninja where it is installed (scripts/setup_debian.sh installs it): it keeps both cores
# busy to the end of the build, where make waits target by target (the ASan + UBSan
# build: 488 s against 517 s). A build folder keeps the generator it was made with.
generator=()
command -v ninja > /dev/null && generator=(-G Ninja)
# The simulator (the test bed) is built uninstrumented and optimized in both builds.
simulator_flags="-fno-sanitize=all;-O2"
# --as-needed: Debian's gcc links with it by default, but not when any -fsanitize is
# given (its link spec holds %{!fsanitize=*:--as-needed}). Without it every library
# recorded every PCL, VTK and OpenCV library it was linked with, a test program loaded
# 274 shared libraries instead of 40, and its start took 0.38 s instead of 0.10 s
# under ASan, of which the dynamic loader's symbol lookups were most: for each of the
# suite's 406 test starts and every tool a test runs.
# No precompiled header: the test programs compile in a few unity batches, 8 in the ASan
# build and 1 in the TSan build, and the header (25 s) saved about 3 s in each.
configure() { # build_dir flags [cmake options]
  local gen=("${generator[@]}")
  [ -f "$1/CMakeCache.txt" ] && gen=()
  cmake -S "$root" -B "$1" "${gen[@]}" -DCMAKE_BUILD_TYPE=RelWithDebInfo -DPCL_RAST_BUILD_TESTS=ON \
    -DCMAKE_CXX_FLAGS_RELWITHDEBINFO="-O1 -g1 -fno-omit-frame-pointer" \
    -DPCL_RAST_TEST_OPTIMIZATION="-O1" -DPCL_RAST_TEST_PCH=OFF \
    -DCMAKE_CXX_FLAGS="$2" -DCMAKE_EXE_LINKER_FLAGS="$2 -Wl,--as-needed" \
    -DCMAKE_SHARED_LINKER_FLAGS="$2 -Wl,--as-needed" \
    "${@:3}" > "$1.configure.log" 2>&1
}

for kind in "${kinds[@]}"; do
  start=$(date +%s)
  case "$kind" in
  asan | asan-full)
    # UBSan's checks in the focused build: those ASan cannot stand in for. Leaving out
    # null, alignment, object-size, pointer-overflow, vptr and the nonnull attributes
    # (bad pointers end in an ASan report or a SEGV anyway) compiles the libraries'
    # heaviest translation unit in 46 s instead of 55 s (ASan alone: 39 s).
    # float-cast-overflow is not in gcc's "undefined" group: named in both builds.
    ubsan="shift,integer-divide-by-zero,signed-integer-overflow,float-cast-overflow"
    ubsan+=",bounds,vla-bound,bool,enum,return,unreachable"
    build="$root/build-asan"
    if [ "$kind" = asan-full ]; then
      build="$root/build-asan-full"
      ubsan="undefined,float-cast-overflow"
    fi
    # Eigen's memory, allocated and freed the way Debian's prebuilt PCL (C++14, no
    # ASan) does it. Template code instantiated both in PCL's libraries and in ours
    # (Eigen::internal::aligned_malloc, shared_ptr<PointCloud<...>>'s deleter, ...)
    # is one symbol at run time: the dynamic linker takes the first copy it finds for
    # every caller, and which comes first depends on the programs' library order
    # (session 30's merge of the test programs changed it). Two differences made the
    # copies disagree, and ASan reported blocks that one copy allocated and another
    # freed: under ASan (__SANITIZE_ADDRESS__) Eigen keeps an offset before each block
    # instead of trusting malloc's alignment (EIGEN_MALLOC_ALREADY_ALIGNED), and in
    # C++17 Eigen's classes drop their own operator new for the language's aligned
    # new (EIGEN_HAS_CXX17_OVERALIGN), so that a cloud from `new` in our code was
    # freed with free() by PCL's copy of its deleter. Both set as in PCL's build:
    # ASan's malloc aligns to 16 bytes as glibc's does (checked for 100,000 sizes,
    # session 30), and these builds keep Eigen's asserts (no NDEBUG), one of which
    # checks exactly that. In the Release build the two ways are the same malloc.
    eigen_malloc="-DEIGEN_MALLOC_ALREADY_ALIGNED=1 -DEIGEN_HAS_CXX17_OVERALIGN=0"
    # The focused build leaves the test programs' own code uninstrumented: it is glue
    # around the libraries and tools under test, whose templates are instantiated in
    # the libraries (PCL_INSTANTIATE), and ASan's instrumentation doubled its compile
    # time (test_slam_tool.cpp: 21 s against 11 s without the precompiled header;
    # session 29). Their heap is still ASan's: a library that overruns a test's buffer
    # or leaks is still reported.
    # PCL_RAST_TESTS_SANITIZED: tests that drive long simulated loops drive shorter ones
    # here (test_rast_slam.cpp); uninstrumented test code cannot tell by itself.
    test_flags="-fno-sanitize=undefined,float-cast-overflow;-DPCL_RAST_TESTS_SANITIZED"
    [ "$kind" = asan ] && test_flags="-fno-sanitize=all;-DPCL_RAST_TESTS_SANITIZED"
    configure "$build" "-fsanitize=address,$ubsan -fno-sanitize-recover=$ubsan $eigen_malloc" \
      "-DPCL_RAST_TEST_EXTRA_FLAGS=$test_flags" \
      "-DPCL_RAST_SIMULATOR_FLAGS=$simulator_flags"
    # malloc_context_size=10: shorter allocation stacks, a faster suite, same findings.
    # intercept_tls_get_addr=0: with Debian 12's glibc, LeakSanitizer's record of the
    # dynamic TLS blocks of pcl_rast_localize held a bogus range ("DTLS 27 at
    # 0x224b-0x40000334d") and its tracer crashed on it at every exit of
    # HostileSequence/localize_pcd; LSan then does not scan dynamic TLS for pointers.
    export ASAN_OPTIONS="halt_on_error=1:detect_leaks=1:detect_odr_violation=0:malloc_context_size=10:intercept_tls_get_addr=0"
    export LSAN_OPTIONS="suppressions=$supp/lsan.supp:print_suppressions=0"
    export UBSAN_OPTIONS="halt_on_error=1:print_stacktrace=1:suppressions=$supp/ubsan.supp"
    # install_and_consume_package builds a project without the sanitizer flags against
    # these instrumented libraries, which then lack their runtime: it runs in the normal
    # build only.
    # Three tests measure accuracy only, by running code that shorter tests of the
    # whole suite also run, and run in the normal build only (the focused set does not
    # build their programs at all):
    # - the tunnel at 26 m/s, with and without the vehicle prior (raw sweeps with point
    #   times, traffic and the vehicle prior: OdometryTraffic.StandingEgo...);
    # - raw sweeps compensated four ways against instantaneous scans (point times: the
    #   same test; azimuth times: OdometryDeskew.CompensatingInstantaneousScans...);
    # - GICP against RasterORB on a turned KITTI pair, mostly PCL's GICP (RasterORB
    #   behind a Registration::Ptr: PclPipelines.RasterOrbTakesGicpsPlace...).
    skipped='install_and_consume_package|OdometryTraffic\.ATunnelAtSpeedKeepsTheVehiclesVelocity'
    skipped+='|OdometryDeskew\.RawSweepsAreCompensatedFromPointTimesOrFromTheAzimuth'
    skipped+='|PclPipelines\.RasterOrbRecoversAThirtyDegreeTurnWhereGicpDoesNot'
    targets=(all)
    select=()
    if [ "$kind" = asan ]; then
      # The focused set: the programs whose tests hand the libraries and tools what a
      # user would (lying files, signals, full disks, sessions, feature clouds as PCD),
      # keep memory of their own (spill file, map tiles, appearance index, voxel
      # hashes, visibility image, the render), run hand-vectorized code (motion
      # compensation), or run the whole SLAM and its tools. Not here: the simulator's
      # tests (it is uninstrumented), the accuracy tests of long simulated drives,
      # localization and session merging beyond what their tools' tests run, the
      # compile-only header check and the doc example. They are the programs
      # test_threaded and test_sanitized of test/CMakeLists.txt, but for the former's
      # localization tests (MapLocalization, SessionLocalizer: the Release suite, and
      # the background placements under TSan), whose code runs here through
      # pcl_rast_localize (LocalizeTool.*, HostileSequence.*/localize_pcd).
      targets=(test_threaded test_sanitized)
      # Their tests, by the label test/CMakeLists.txt gives each test: its program. A
      # program left out is never run, not even from an old binary in the build folder.
      select=(-L "^($(IFS='|'; echo "${targets[*]}"))\$")
      # Accuracy on simulated drives, 14-40 s each under ASan, whose code the tests
      # kept here run too: reproducibility (a second run of ClosesTheLoop...), revisits
      # and loop corrections (the loop closing of ClosesTheLoop...), bundle adjustment
      # inside the SLAM (BundleAdjustment.*), drift and a young map's tilt (the
      # odometry's other tests), the VLP-16 prior (the same path on KITTI scans).
      long=(RastSlam.DeterministicModeIsReproducible RastSlam.RevisitsDoNotGrowTheLoopDatabase
            RastSlam.LoopCorrectionGoesToTheYoungMapsEdges
            RastSlam.MapPointsAreBuiltOnlyForABundleAdjustment
            RastSlam.FeaturesOnDemandSkipFramesButNotKeyFramesNorTheLoop
            Odometry.SimulatedDriveHasSmallDriftAndConsistentKeyFrames
            Odometry.YoungMapTakesEveryScanSoTheStartDoesNotTilt
            OdometryRealData.Vlp16WeakFeaturesTakeHeightAndTiltFromThePrior)
      # Session 65 (CI at 40 minutes on 2 cores): tests whose code a kept test runs
      # again, 10-56 s each here.
      # - accuracy: the loop's correction (SpillingToDisk runs that SLAM and its loop
      #   twice), the raw KITTI drive's smoothness (the other real-data odometry tests
      #   read and track real scans);
      # - two runs compared for equality, the look-ahead on and off (every tool run
      #   here has it on), the compensation off (CompensatedScansGiveTheSamePosesToo);
      # - a parameter handed on (the visibility margin);
      # - the loop detector's decisions on its simulated loop, which rebuilds that loop
      #   in each test (12-14 s): its index, retrieval and verification run in the
      #   three kept (RevisitFound..., DriftedRevisit..., DatabaseBookkeeping);
      # - the lying scans through pcl_rast_odometry as PLY and .bin: the same reader
      #   reads them through pcl_rast_slam, and pcl_rast_odometry gets them as PCD.
      long+=(RastSlam.ClosesTheLoopAndImprovesTheTrajectory
             OdometryRealData.KittiRawMotionIsSmooth
             SlamTool.TheLookAheadChangesNoPose OdometryTool.TheLookAheadChangesNoPose
             OdometryLookahead.WithoutCompensationThePosesAreTheSame
             SlamTool.TheVisibilityMarginIsHandedToTheOdometry
             LoopDetector.Deterministic LoopDetector.RecentKeyFramesExcluded
             LoopDetector.OppositeDirectionRevisit LoopDetector.NonOverlappingPairsRejected
             LoopDetector.TooLittleStructureLeavesTheDenseCheckUndecided)
      skipped+="|$(IFS='|'; echo "${long[*]}" | sed 's/\./\\./g')"
      # (a parameterized test's name ends in "  # GetParam() = ...")
      skipped+='|EveryScanTool/HostileSequence\..*/odometry_(ply|bin) .*'
      # The lying scans (50 and more) through pcl_rast_features, a start of the tool
      # each (43 s here): the same files are read in one process by HostileScans.*, and
      # the other tools are handed them among good scans by HostileSequence.*.
      skipped+='|HostileTools\.FeaturesGivesAClearErrorOnEveryLyingScan'
      skipped+='|MapLocalization\..*|SessionLocalizer\..*'
    fi
    # The build runs the tests to list them (gtest_discover_tests): same options.
    cmake --build "$build" -j"$jobs" --target "${targets[@]}" > "$build.build.log" 2>&1 ||
      { tail -30 "$build.build.log"; exit 1; }
    # The longest tests first, also in a fresh build folder (scripts/seed_test_costs.sh):
    # the focused set by its own times, the whole suite by the Release suite's.
    seed=release
    [ "$kind" = asan ] && seed=asan
    "$root/scripts/seed_test_costs.sh" "$build" "$seed"
    log="$build.ctest.log"
    if ! (cd "$build" && ctest -j"$jobs" --output-on-failure --timeout 1800 \
            --no-tests=error "${select[@]}" -E "^($skipped)\$" 2>&1 | tee "$log"
          exit "${PIPESTATUS[0]}"); then
      # LeakSanitizer's stop-the-world tracer sometimes crashes at a process's exit
      # ("Tracer caught signal 11", google/sanitizers#1353): the program had finished,
      # LSan could not check it, and the exit code fails the test. When there are as
      # many tracer crashes as failed tests and no sanitizer reported anything, the
      # failed tests run once more; anything else stays a failure.
      failed=$(grep -c -- '\*\*\*Failed' "$log" || true)
      crashed=$(grep -c 'Tracer caught signal 11' "$log" || true)
      if [ "$failed" -gt 0 ] && [ "$crashed" -ge "$failed" ] &&
         ! grep -qE 'ERROR: (AddressSanitizer|LeakSanitizer: detected)|runtime error:' "$log"; then
        echo "run_sanitizers.sh: $failed test(s) failed by the LeakSanitizer tracer crash;" \
             "running them once more"
        (cd "$build" && ctest --rerun-failed --output-on-failure --timeout 1800)
      else
        exit 1
      fi
    fi
    unset ASAN_OPTIONS LSAN_OPTIONS UBSAN_OPTIONS
    ;;
  tsan)
    build="$root/build-tsan"
    configure "$build" "-fsanitize=thread" -DPCL_RAST_TESTS_BUILD_TOOLS=OFF \
      "-DPCL_RAST_SIMULATOR_FLAGS=$simulator_flags"
    # The tests below run one program, pcl_rast_slam: the other tools are not built.
    # MapLocalization's background placements (a thread per attempt) are checked by the
    # test that backs off: the only one of its file that starts them. The odometry's
    # look-ahead (its thread, on by default in the tools) by the SlamTool tests below
    # and that test of MapLocalization; its own program runs under ASan (here it cost a
    # TSan build of it and 130 CPU-s, session 28).
    targets=(test_threaded pcl_rast_slam)
    # The build runs the tests to list them (gtest_discover_tests): same options.
    export TSAN_OPTIONS="halt_on_error=1:second_deadlock_stack=1:suppressions=$supp/tsan.supp"
    cmake --build "$build" -j"$jobs" --target "${targets[@]}" > "$build.build.log" 2>&1 ||
      { tail -30 "$build.build.log"; exit 1; }
    # Tests that run RastSlam only in deterministic mode start no thread (the stages run
    # in sequence on the caller's): TSan has nothing to check there, and they are the
    # longest (8.5 of its 13.5 CPU-minutes). The ASan build runs them.
    deterministic_only='ClosesTheLoopAndImprovesTheTrajectory|DeterministicModeIsReproducible'
    deterministic_only+='|MapPointsAreBuiltOnlyForABundleAdjustment|SpillingToDiskChangesNothingButMemory'
    deterministic_only+='|RevisitsDoNotGrowTheLoopDatabase|LoopCorrectionGoesToTheYoungMapsEdges'
    deterministic_only+='|FeaturesOnDemandSkipFramesButNotKeyFramesNorTheLoop'
    # The tool's tests whose runs start its threads in ways the others do not: every
    # output of a threaded run, an error in the loop closing thread, a second drive
    # merged into a session. The others run the same threads again (the look-ahead's
    # among them) or stop before any: 105 of the phase's 372 CPU-s (session 29).
    tool_tests='WritesEveryOutputWithTheContractedContent'
    tool_tests+='|AnErrorInTheLoopClosingThreadStillWritesEveryOutputAndExitsThree'
    tool_tests+='|ExtendsASessionWithASecondDriveAndKeepsAStrangerSeparate'
    # Its longest tests by its own times: the placements' back-off (about 50 s here, 4 s
    # in Release) was declared last and ran alone at the end.
    "$root/scripts/seed_test_costs.sh" "$build" tsan
    (cd "$build" && ctest -j"$jobs" --output-on-failure --timeout 1800 \
       -R "^((RastSlam|LocalMapping|BundleAdjustment)\.|SlamTool\.($tool_tests)\$|MapLocalization\.PlacementsBackOff)" \
       -E "^RastSlam\.($deterministic_only)\$")
    unset TSAN_OPTIONS
    ;;
  *)
    echo "run_sanitizers.sh: unknown kind '$kind' (asan, asan-full, tsan)" >&2
    exit 1
    ;;
  esac
  echo "run_sanitizers.sh: $kind clean in $(( $(date +%s) - start )) s"
done
