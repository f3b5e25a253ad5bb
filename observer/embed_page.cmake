# Embeds the page into the observer at build time (nothing generated is committed):
#   cmake -DINPUT=index.html -DOUTPUT=page_data.cpp -P embed_page.cmake
# writes deif::observer::PageHtml() returning the file's bytes.
file(READ "${INPUT}" hex HEX)
string(REGEX REPLACE "([0-9a-f][0-9a-f])" "0x\\1," bytes "${hex}")
file(WRITE "${OUTPUT}"
  "// Generated from observer/page/index.html by observer/embed_page.cmake: do not edit.\n"
  "#include \"observer/page.hpp\"\n"
  "namespace deif::observer {\n"
  "namespace {\n"
  "const unsigned char kPage[] = {${bytes}};\n"
  "}  // namespace\n"
  "std::string PageHtml() { return std::string(reinterpret_cast<const char*>(kPage), sizeof kPage); }\n"
  "}  // namespace deif::observer\n")
