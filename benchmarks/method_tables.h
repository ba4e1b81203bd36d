// The measured tables of docs/method.md: `cip_bench method [--quick] [--shared-data DIR]` prints them as
// Markdown, every row from builds made side by side in the same run.
#pragma once
#include <string>

namespace cipbench {

void methodTables(const std::string& sharedData, bool quick);

}  // namespace cipbench
