#pragma once
/// \file png_image.h
/// \brief A PNG written by the library or a tool, as a cv::Mat with three channels in
/// BGR order, the way cv::imread(path) gave it. Read with pcl::rast::loadPng: the test
/// programs do not link OpenCV's imgcodecs, whose libraries made each test's start
/// several times slower (visualization/include/pcl/visualization/png_io.h).

#include <exception>
#include <iostream>
#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>
#include <pcl/visualization/png_io.h>
#include <string>

namespace pcl_rast_test {

/// The picture at \a path, or an empty cv::Mat (with the reason printed) when it
/// cannot be read.
inline cv::Mat
readPngAsBgr(const std::string& path)
{
  pcl::rast::Image8 png;
  try {
    png = pcl::rast::loadPng(path);
  } catch (const std::exception& e) {
    std::cout << e.what() << "\n";
    return {};
  }
  const cv::Mat stored(png.height, png.width, CV_8UC(png.channels), png.pixels.data());
  cv::Mat bgr;
  switch (png.channels) {
  case 1:
    cv::cvtColor(stored, bgr, cv::COLOR_GRAY2BGR);
    break;
  case 2: { // grey and alpha: the grey
    cv::Mat grey;
    cv::extractChannel(stored, grey, 0);
    cv::cvtColor(grey, bgr, cv::COLOR_GRAY2BGR);
    break;
  }
  case 4:
    cv::cvtColor(stored, bgr, cv::COLOR_BGRA2BGR);
    break;
  default:
    bgr = stored.clone();
  }
  return bgr;
}

} // namespace pcl_rast_test
