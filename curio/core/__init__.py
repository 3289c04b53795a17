"""The runtime core: clock, bus, topics, messages, geometry, configuration, parts, file I/O.

Everything else in Curio builds on these modules; they import nothing from the rest of the
package.
"""
