// The translation unit that builds the test suites' shared precompiled header (tests/CMakeLists.txt,
// cip_test_pch); it has no code of its own.
