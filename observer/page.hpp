// The live page (observer/page/index.html: plain HTML and JavaScript, no build step),
// embedded in the binary at build time by observer/embed_page.cmake.
#pragma once

#include <string>

namespace deif::observer {

std::string PageHtml();

}  // namespace deif::observer
