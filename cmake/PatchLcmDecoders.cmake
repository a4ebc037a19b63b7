# Hardens lcm-gen C++ output: every variable-length array is checked against the
# bytes left in the buffer before it is allocated, and strings of length < 1 are
# rejected. Each element takes at least one byte, so a count larger than the
# remaining bytes can only come from a corrupt or hostile message.
file(GLOB headers "${DIR}/*.hpp")
foreach(h ${headers})
  file(READ "${h}" text)
  string(REGEX REPLACE
    "\n([ ]*)this->([A-Za-z0-9_]+)\\.resize\\(this->([A-Za-z0-9_]+)\\);"
    "\n\\1if (this->\\3 < 0 || this->\\3 > maxlen - pos) return -1;\n\\1this->\\2.resize(this->\\3);"
    text "${text}")
  string(REPLACE "if(__elem_len > maxlen - pos) return -1;"
                 "if(__elem_len < 1 || __elem_len > maxlen - pos) return -1;"
                 text "${text}")
  string(REGEX REPLACE "if\\(__([A-Za-z0-9_]+)_len__ > maxlen - pos\\) return -1;"
                 "if(__\\1_len__ < 1 || __\\1_len__ > maxlen - pos) return -1;"
                 text "${text}")
  file(WRITE "${h}" "${text}")
endforeach()
