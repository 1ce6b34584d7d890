// The DICOM formats of what the commands that write DICOM write (pose --dicom-out, batch, dicom export).
#pragma once

#include <CLI/CLI.hpp>

#include <string>

#include "posewarp/api/dicom.h"

namespace posewarp::cli {

struct DicomFormatOptions {
  std::string seg = "binary", ct = "series";

  bool defaults() const { return seg == "binary" && ct == "series"; }
  // Into the options of the derived series.
  void apply(api::DerivedSeriesOptions* options) const {
    options->seg_format = seg == "labelmap" ? api::SegFormat::kLabelMap : api::SegFormat::kBinary;
    options->ct_format = ct == "enhanced" ? api::CtFormat::kEnhanced : api::CtFormat::kSeries;
  }
};

inline void add_dicom_format_options(CLI::App* cmd, DicomFormatOptions& o) {
  cmd->add_option("--seg-format", o.seg,
                  "Labels as a binary SEG (a frame per segment and slice; every SEG reader knows it) or a labelmap "
                  "SEG (DICOM Supplement 243: a frame per slice, each pixel its segment's number; much faster for a "
                  "PACS to store, newer readers only)")
      ->check(CLI::IsMember({"binary", "labelmap"}))
      ->capture_default_str();
  cmd->add_option("--ct-format", o.ct,
                  "CT as a series of single-frame CT images or as one multi-frame Enhanced CT image")
      ->check(CLI::IsMember({"series", "enhanced"}))
      ->capture_default_str();
}

}  // namespace posewarp::cli
